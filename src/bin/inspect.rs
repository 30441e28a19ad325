//! `validate` and `info`: reading a dataset back, ours or not. The library does the work
//! (`surgvla::export::validate`); here are the arguments, the printing, and the exit code
//! (0 valid, 1 invalid, 2 could not run).

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;
use surgvla::export::validate::{Report, ValidateOptions, validate};
use surgvla::task::TaskId;

/// Findings printed in the human summary (the JSON has them all).
const PRINTED_FINDINGS: usize = 50;

#[derive(Args, Debug)]
pub struct ValidateArgs {
    /// The dataset: a LeRobot folder, an RLDS version folder (or the data dir above it), a DP3
    /// zarr store, an MCAP file or a folder of them.
    pub path: PathBuf,
    /// Print the report as JSON: {"valid", "format", "errors": [{"file", "episode", "frame",
    /// "check", "message"}], "warnings": [...], ...}.
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

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// The dataset (as for `validate`).
    pub path: PathBuf,
    /// Print as JSON.
    #[arg(long)]
    pub json: bool,
    /// Also draw the dataset as PNG: a histogram of episode lengths per task, and the range
    /// of each state and action dimension (reads every episode: LeRobot and RLDS datasets).
    #[arg(long, value_name = "FILE.png")]
    pub plot: Option<PathBuf>,
}

fn step_limits() -> std::collections::BTreeMap<String, usize> {
    TaskId::ALL
        .iter()
        .map(|t| (t.code().to_string(), t.step_limit() as usize))
        .collect()
}

fn place(path: &std::path::Path) -> String {
    path.display().to_string()
}

pub fn run_validate(args: &ValidateArgs) -> Result<(), CliError> {
    let options = ValidateOptions {
        quick: args.quick,
        step_limits: step_limits(),
        threads: args.threads,
    };
    let mut report = validate(&args.path, &options)?;
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

pub fn run_info(args: &InfoArgs) -> Result<(), CliError> {
    let options = ValidateOptions {
        quick: true,
        step_limits: step_limits(),
        threads: 0,
    };
    let report = validate(&args.path, &options)?;
    if let Some(plot) = &args.plot {
        draw_plot(&args.path, plot)?;
    }
    let facts = &report.facts;
    if args.json {
        let json = serde_json::json!({
            "path": report.path,
            "format": report.format,
            "episodes": report.episodes,
            "frames": report.frames,
            "bytes": report.bytes,
            "fps": facts.fps,
            "robot_type": facts.robot_type,
            "features": facts.features,
            "tasks": facts.tasks,
            "generator": facts.generator,
            "collection": facts.collection,
            "quick_check_errors": report.errors.len(),
        });
        say!("{}", serde_json::to_string_pretty(&json)?);
        return quick_check_result(&report, &args.path, true);
    }
    say!("path       {}", place(&report.path));
    say!("format     {}", report.format);
    say!("episodes   {}", report.episodes);
    say!("frames     {}", report.frames);
    say!("size       {:.1} MB", report.bytes as f64 / 1e6);
    if let Some(fps) = facts.fps {
        say!("fps        {fps}");
    }
    if let Some(robot) = &facts.robot_type {
        say!("robot      {robot}");
    }
    if let Some(generator) = &facts.generator {
        say!("generator  {generator}");
    }
    if !facts.collection.is_null() {
        say!("collection {}", facts.collection);
    }
    say!("features");
    for feature in &facts.features {
        say!(
            "  {:<40} {:<28} {:?}",
            feature.name,
            feature.dtype,
            feature.shape
        );
    }
    if !facts.tasks.is_empty() {
        say!("tasks (episodes)");
        for (task, episodes) in &facts.tasks {
            say!("  {episodes:>6}  {task}");
        }
    }
    quick_check_result(&report, &args.path, false)
}

/// `info` exits 1 when its quick check found errors (the dataset is invalid, or parts of it
/// cannot be read), after printing what it could read.
/// (`--json` prints no findings: its count is in the JSON.)
fn quick_check_result(report: &Report, path: &std::path::Path, json: bool) -> Result<(), CliError> {
    if report.errors.is_empty() {
        return Ok(());
    }
    for finding in report
        .errors
        .iter()
        .take(if json { 0 } else { PRINTED_FINDINGS })
    {
        say!("error: {finding}");
    }
    Err(CliError::invalid(format!(
        "the quick check found {} problem(s): run `surgvla validate {}`",
        report.errors.len(),
        place(path)
    )))
}

/// `info --plot`: every episode read into its profile, drawn.
fn draw_plot(dataset: &std::path::Path, plot: &std::path::Path) -> Result<(), CliError> {
    let mut source = surgvla::export::open_source(dataset)?;
    let profile = surgvla::export::profile::profile(source.as_mut())?;
    let (histograms, ranges) = surgvla::export::profile::chart_parts(&profile, 12);
    let title = format!(
        "{}: episode lengths per task, state and action ranges",
        dataset.display()
    );
    let canvas = surgvla::chart::plots::dataset_chart(&title, &histograms, &ranges);
    let png = canvas
        .png()
        .map_err(|e| CliError::invalid(format!("encoding {}: {e}", plot.display())))?;
    surgvla::export::write_atomically(plot, &png)?;
    Ok(())
}
