//! `surgvla record`: one expert episode as an MCAP recording for Foxglove.

use crate::error::CliError;
use std::path::PathBuf;
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

#[derive(clap::Args, Debug)]
pub(crate) struct RecordArgs {
    /// Task name (gauze_pick, ...) or id (T1-1, ...).
    #[arg(long, default_value = "gauze_pick")]
    task: TaskId,
    /// Episode seed: decides the spawn positions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The MCAP file to write (must not exist).
    #[arg(long)]
    out: PathBuf,
}

pub(crate) fn run_record(args: &RecordArgs) -> Result<(), CliError> {
    if args.out.exists() {
        return Err(CliError::usage(format!(
            "{} already exists; remove it or choose another path",
            args.out.display()
        )));
    }
    let library = ExpertLibrary::builtin()?;
    let options = surgvla::collect::record::RecordOptions::default();
    let collect = surgvla::collect::run::CollectOptions {
        tasks: vec![args.task],
        episodes_per_task: 1,
        seed: args.seed,
        ..Default::default()
    };
    let features = surgvla::episode::FeatureSet {
        mask: true,
        ..Default::default()
    };
    let info = surgvla::collect::run::dataset_info(&collect, features, &library);
    let (episode, bytes) =
        surgvla::collect::record::record_mcap(&library, args.task, args.seed, &options, &info)
            .map_err(|e| {
                use surgvla::collect::record::{RecordError, RecordMcapError};
                match e {
                    RecordMcapError::Export(e) => CliError::from(e),
                    RecordMcapError::Record(RecordError::Plan(e)) => CliError::from(e),
                    RecordMcapError::Record(RecordError::Spawn(e)) => CliError::from(e),
                }
            })?;
    surgvla::export::write_atomically(&args.out, &bytes)
        .map_err(|e| CliError::from(e).context(format!("writing {}", args.out.display())))?;
    say!(
        "{} ({}), seed {}: {} steps, {}; wrote {} ({:.1} MB)",
        args.task.code(),
        args.task.name(),
        args.seed,
        episode.steps.len(),
        if episode.meta.success {
            "success"
        } else {
            "failure"
        },
        args.out.display(),
        bytes.len() as f64 / 1e6
    );
    Ok(())
}
