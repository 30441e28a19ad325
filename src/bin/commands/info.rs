//! `surgvla info`: what a dataset is (format, counts, features, tasks, provenance), with
//! `--quick` checks and `--plot`.

use crate::commands::validate::step_limits;
use crate::commands::validate::{PRINTED_FINDINGS, place};
use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;
use surgvla::export::validate::{Report, ValidateOptions, validate};

#[derive(Args, Debug)]
pub(crate) struct InfoArgs {
    /// The dataset (as for `validate`).
    pub path: PathBuf,
    /// Print as JSON.
    #[arg(long)]
    pub json: bool,
    /// Also draw the dataset as PNG: a histogram of episode lengths per task, and the range
    /// of each state and action dimension, named as the dataset names them, on one scale per
    /// unit (reads every episode: LeRobot and RLDS datasets).
    #[arg(long, value_name = "FILE.png", value_parser = crate::app::png_path)]
    pub plot: Option<PathBuf>,
}

pub(crate) fn run_info(args: &InfoArgs) -> Result<(), CliError> {
    let options = ValidateOptions {
        quick: true,
        step_limits: step_limits(),
        threads: 0,
        lint: false,
        profile: None,
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
            "task_ids": facts.task_ids,
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
    if let Some(collection) = &facts.collection {
        say!("collection {collection}");
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
    if !facts.task_ids.is_empty() {
        say!("tasks (episodes, instructions)");
        for (id, fact) in &facts.task_ids {
            let instructions: Vec<&str> = fact.instructions.iter().map(String::as_str).collect();
            say!(
                "  {id:<6} {:>6}  {}",
                fact.episodes,
                instructions.join(" | ")
            );
        }
    } else if !facts.tasks.is_empty() {
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
