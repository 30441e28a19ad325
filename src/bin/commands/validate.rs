//! `surgvla validate`: a dataset checked frame by frame, every defect named (exit 0 valid, 1
//! invalid, 2 nothing recognisable); `--replay` replays it in the simulator.

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;
use surgvla::export::validate::{Report, ValidateOptions, validate};
use surgvla::task::TaskId;

/// Findings printed in the human summary (the JSON has them all).
pub(crate) const PRINTED_FINDINGS: usize = 50;

#[derive(Args, Debug)]
pub(crate) struct ValidateArgs {
    /// The dataset: a LeRobot folder, an RLDS version folder (or the data dir above it), a DP3
    /// zarr store, an MCAP file or a folder of them.
    pub path: PathBuf,
    /// Print the report as JSON: {"valid", "format", "errors": [{"file", "episode", "frame",
    /// "check", "message"}], "warnings": [...], ...}; when the check cannot run (exit 2),
    /// {"valid": false, "format": null, "error": "why", "errors": [], "warnings": []}.
    #[arg(long)]
    pub json: bool,
    /// Metadata and one frame per episode instead of every frame.
    #[arg(long)]
    pub quick: bool,
    /// Also re-simulate every episode from its recorded seed, replay its actions and confirm
    /// success and the recorded frames (datasets surgvla collected; LeRobot image mode or RLDS).
    #[arg(long)]
    pub replay: bool,
    /// Worker threads for the full pass (0: one per core; at most 8 per core).
    #[arg(long, default_value_t = 0, value_parser = crate::threads_arg)]
    pub threads: usize,
}

pub(crate) fn step_limits() -> std::collections::BTreeMap<String, usize> {
    TaskId::ALL
        .iter()
        .map(|t| (t.code().to_string(), t.step_limit() as usize))
        .collect()
}

pub(crate) fn place(path: &std::path::Path) -> String {
    path.display().to_string()
}

pub(crate) fn run_validate(args: &ValidateArgs) -> Result<(), CliError> {
    let options = ValidateOptions {
        quick: args.quick,
        step_limits: step_limits(),
        threads: args.threads,
    };
    let mut report = match validate(&args.path, &options) {
        Ok(report) => report,
        Err(error) => {
            let error = CliError::from(error);
            if args.json {
                // A report on every exit: why the check could not run, as its error.
                let json = serde_json::json!({
                    "valid": false,
                    "format": null,
                    "path": args.path,
                    "error": error.message(),
                    "errors": [],
                    "warnings": [],
                });
                say!("{}", serde_json::to_string_pretty(&json)?);
            }
            return Err(error);
        }
    };
    if args.replay {
        let reads = surgvla::export::registry::of_layout(report.format)
            .is_some_and(|format| format.capabilities().reads);
        if !reads {
            return Err(CliError::usage(format!(
                "--replay reads {} datasets; {} is {}",
                surgvla::export::registry::titles(|c| c.reads, "or"),
                place(&report.path),
                report.format
            )));
        }
        if report.valid {
            let bar = crate::progress::episode_bar(report.episodes, "replaying");
            let found = surgvla::collect::replay::replay_dataset(&report.path, args.threads)?;
            bar.finish_and_clear();
            report.add_errors(found.errors);
            report.warnings.extend(found.warnings);
        }
    }
    if args.json {
        say!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report)?;
    }
    if report.valid {
        Ok(())
    } else {
        Err(CliError::invalid(format!(
            "{} is not a valid {} dataset: {} error{}",
            place(&report.path),
            report.format,
            report.errors.len(),
            if report.errors.len() == 1 { "" } else { "s" }
        )))
    }
}

fn print_report(report: &Report) -> Result<(), CliError> {
    say!(
        "{}: {} dataset, {} episodes, {} frames{}",
        place(&report.path),
        report.format,
        report.episodes,
        report.frames,
        if report.valid { ": valid" } else { "" }
    );
    for (label, findings) in [("error", &report.errors), ("warning", &report.warnings)] {
        for finding in findings.iter().take(PRINTED_FINDINGS) {
            say!("{label}: {finding}");
        }
        if findings.len() > PRINTED_FINDINGS {
            say!(
                "... {} more {label}s (--json lists them all)",
                findings.len() - PRINTED_FINDINGS
            );
        }
    }
    Ok(())
}
