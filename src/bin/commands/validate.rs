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
    /// Metadata, every row's numbers, and one frame per row group or video file instead of
    /// every frame.
    #[arg(long)]
    pub quick: bool,
    /// Also re-simulate every episode from its recorded seed, replay its actions and confirm
    /// success and the recorded frames (datasets surgvla collected; LeRobot image mode or RLDS).
    #[arg(long)]
    pub replay: bool,
    /// Worker threads for the full pass (0: one per core; at most 8 per core).
    #[arg(long, default_value_t = 0, value_parser = crate::app::threads_arg)]
    pub threads: usize,
    /// Judge whether the data is any good to train on (the default): frozen or jumping
    /// actions, outliers, state/action lag, quaternions, units, gripper range, episode lengths
    /// against action chunks, instructions, splits; with every frame decoded (not --quick),
    /// blank, frozen and swapped cameras. docs/validate.md lists the checks and thresholds.
    #[arg(long, overrides_with = "no_lint")]
    pub lint: bool,
    /// Skip the quality lint: the format's checks only.
    #[arg(long, overrides_with = "lint")]
    pub no_lint: bool,
    /// Also check a community's contribution guide: open-h (Open-H-Embodiment: LeRobot v2.1
    /// video, action and observation.state, observation.images.* cameras, splits, >= 20 Hz and
    /// 480p, meta/README.md with a synchronisation section), every frame decoded.
    #[arg(long, value_enum)]
    pub profile: Option<ProfileArg>,
    /// What makes the exit code 1: an error (the default), or a warning too (a CI gate).
    #[arg(long, value_enum, default_value_t = FailOn::Error)]
    pub fail_on: FailOn,
}

/// A contribution guide to check against.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ProfileArg {
    /// Open-H-Embodiment's.
    OpenH,
}

/// What fails `validate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FailOn {
    /// Errors: data a trainer would mis-learn from, or that does not read.
    Error,
    /// Errors and warnings.
    Warning,
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
        lint: !args.no_lint,
        profile: args.profile.map(|p| match p {
            ProfileArg::OpenH => surgvla::export::validate::Profile::OpenH,
        }),
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
    if report.valid && args.fail_on == FailOn::Warning && !report.warnings.is_empty() {
        return Err(CliError::invalid(format!(
            "{} has {} warning{} (--fail-on warning)",
            place(&report.path),
            report.warnings.len(),
            if report.warnings.len() == 1 { "" } else { "s" }
        )));
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
        "{}: {} dataset, {}, {}{}",
        place(&report.path),
        report.format,
        crate::say::n(report.episodes, "episode"),
        crate::say::n(report.frames, "frame"),
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
    if !report.lint.is_empty() {
        say!("lint:");
        for summary in &report.lint {
            say!("  {summary}");
        }
    }
    Ok(())
}
