//! `surgvla report`: several evaluations' success rates charted side by side.

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub(crate) struct ReportArgs {
    /// The results folders of `surgvla eval` runs (each with its results.json), one bar
    /// colour each, in the order given.
    #[arg(required = true, num_args = 1..)]
    results: Vec<PathBuf>,
    /// The chart to write (PNG).
    #[arg(long)]
    out: PathBuf,
    /// The chart's title.
    #[arg(long, default_value = "success rate per task, 95 % interval")]
    title: String,
}

/// `surgvla report RESULTS_DIR... --out chart.png`: several policies' success rates side by
/// side, the runs named by their policy (by their folder when two share one).
pub(crate) fn run_report(args: &ReportArgs) -> Result<(), CliError> {
    let runs: Vec<surgvla::eval::chart::RunRates> = args
        .results
        .iter()
        .map(|dir| surgvla::eval::chart::read_results(dir))
        .collect::<Result<_, _>>()?;
    let names: Vec<String> = runs
        .iter()
        .zip(&args.results)
        .map(|(run, dir)| {
            let shared = runs.iter().filter(|r| r.policy == run.policy).count() > 1;
            if shared {
                dir.file_name().map_or_else(
                    || dir.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                )
            } else {
                run.policy.clone()
            }
        })
        .collect();
    let chart = surgvla::eval::chart::chart_of(&args.title, &runs, &names);
    surgvla::eval::chart::write_chart(&chart, &args.out)?;
    say!(
        "charted {} runs over {} tasks into {}",
        runs.len(),
        chart.categories.len(),
        args.out.display()
    );
    Ok(())
}
