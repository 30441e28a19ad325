//! `surgvla experts`: the experts' success rates as `collect` would run them, without
//! rendering or writing.

use crate::error::CliError;
use crate::job::JobArgs;
use crate::progress;
use clap::Args;
use surgvla::collect::run::measure_experts;

#[derive(Args, Debug)]
pub(crate) struct ExpertsArgs {
    #[command(flatten)]
    job: JobArgs,
    /// Failed attempts to list (with the seed that reproduces each).
    #[arg(long, default_value_t = 10)]
    show_failures: usize,
}

/// Runs the experts as `collect` would (same attempts, replay check) without rendering or
/// writing, and prints their success rates: the quick check of a new or edited plan.
pub(crate) fn run_experts(args: &ExpertsArgs) -> Result<(), CliError> {
    let (options, library) = args.job.options()?;
    options.check().map_err(CliError::usage)?;
    let mut bars = progress::Bars::new(&options.tasks);
    let report = measure_experts(&options, &library, &mut bars)?;
    bars.clear();
    progress::print_expert_table(&report)?;
    let job = &args.job;
    // `surgvla sim` replays an attempt only with the built-in plans and default scene options.
    let sim_reproduces = job.policies.is_none() && job.distractors == 1 && job.spawn_scale == 1.0;
    let failures = report.failures.iter().filter(|f| f.stage.is_attempt());
    for failure in failures.take(args.show_failures) {
        let code = failure.slot.task.code();
        let seed = failure.seed;
        let hint = if sim_reproduces {
            format!("surgvla sim --task {code} --seed {seed}")
        } else {
            format!("seed {seed}")
        };
        say!(
            "{code} episode {} attempt {} ({}): {}  [{hint}]",
            failure.slot.k,
            failure.attempt,
            failure.stage,
            failure.reason
        );
    }
    Ok(())
}
