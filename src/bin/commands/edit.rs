//! `surgvla edit INPUT --out DIR`: keep, drop, split, remove and rename features, change
//! instructions, in one pass and in the input's own format, video copied without decoding
//! (the library plans, chooses and writes; here are the flags and the printing).

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;
use surgvla::export::edit::{Changes, EditRequest, Planned, Selection, Selector, Splits};

#[derive(Args, Debug)]
pub(crate) struct EditArgs {
    /// The dataset to edit: LeRobot (v3.0 or v2.1, image or video mode) or RLDS; the result
    /// is in the same format and layout.
    input: PathBuf,
    /// Output folder (must not exist or be empty); with --split, one dataset per split in
    /// OUT/NAME.
    #[arg(long)]
    out: PathBuf,
    /// Keep only the episodes this names (repeat: any of them): input indices and ranges
    /// (`0-9,12`), `task=T1-1` (or an instruction), `length>=20` (<, <=, >, >=, =), a
    /// provenance field (`success=true`, `seed=7`, `level=2`, `attempts=1`) or a value another
    /// tool's episodes carry (`KEY=VALUE`), `flagged` (validate --lint names the episode) or
    /// `flagged=errors`.
    #[arg(long, value_name = "SELECTOR", allow_hyphen_values = true)]
    keep: Vec<Selector>,
    /// Leave out the episodes this names (repeat: any of them; same forms as --keep, e.g.
    /// `--drop 1,3,6-8`, `--drop success=false`, `--drop flagged`).
    #[arg(long, value_name = "SELECTOR", allow_hyphen_values = true)]
    drop: Vec<Selector>,
    /// Split the kept episodes: shares drawn per task with --seed (`train=0.8,val=0.1,test=0.1`,
    /// a decimal point in each) or input indices (`train=0-79,val=80-89+95`); any names
    /// (Open-H's `recovery` and `failure` too). One dataset per split under --out, or with
    /// --splits-in-info one dataset whose info.json names them.
    #[arg(long, value_name = "NAME=SHARE,...")]
    split: Option<Splits>,
    /// With --split: write one dataset, its episodes grouped by split in the order given and
    /// the splits recorded in its metadata (LeRobot's info.json `splits`), in place of copies.
    #[arg(long, requires = "split")]
    splits_in_info: bool,
    /// The seed of --split's shares.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Leave features out, comma-separated: depth, mask, environment_state or any feature
    /// key of the input.
    #[arg(long, value_name = "KEY", value_delimiter = ',')]
    remove_feature: Vec<String>,
    /// Rename a feature (repeat): another tool's feature or the camera, e.g.
    /// observation.images.endoscope=observation.images.image.
    #[arg(long, value_name = "OLD=NEW", value_parser = pair)]
    rename_feature: Vec<(String, String)>,
    /// Give every episode this instruction.
    #[arg(long, value_name = "TEXT", conflicts_with = "map_tasks")]
    set_task: Option<String>,
    /// Replace an instruction (repeat), matched exactly: "pick up gauze=pick up the gauze".
    #[arg(long, value_name = "OLD=NEW", value_parser = pair)]
    map_tasks: Vec<(String, String)>,
    /// Encode again the video of episodes that cannot be copied alone (one starting mid-GOP);
    /// without it such an episode stops the edit, named.
    #[arg(long)]
    allow_reencode: bool,
    /// Recompute the pixel statistics of video another tool wrote (its metadata holds
    /// per-episode summaries only) from every decoded frame of the kept episodes.
    #[arg(long)]
    exact_stats: bool,
    /// Print what would be kept, dropped and encoded again, and each result's size; write
    /// nothing.
    #[arg(long)]
    dry_run: bool,
    /// Afterwards read each result back and compare every frame with the input's (copied
    /// video: its sample bytes); a difference exits 1.
    #[arg(long)]
    verify: bool,
    /// Continue an interrupted edit into --out (the same input and flags).
    #[arg(long)]
    resume: bool,
    /// Worker threads (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::app::threads_arg)]
    threads: Option<usize>,
    #[command(flatten)]
    unstated: crate::commands::convert::Unstated,
}

/// `OLD=NEW`, both non-empty.
fn pair(text: &str) -> Result<(String, String), String> {
    match text.split_once('=') {
        Some((old, new)) if !old.trim().is_empty() && !new.trim().is_empty() => {
            Ok((old.to_string(), new.to_string()))
        }
        _ => Err(format!("{text:?}: write OLD=NEW")),
    }
}

impl EditArgs {
    fn request(&self) -> EditRequest {
        EditRequest {
            input: self.input.clone(),
            source: self.unstated.source_options(),
            out: self.out.clone(),
            selection: Selection {
                keep: self.keep.clone(),
                drop: self.drop.clone(),
                splits: self.split.clone(),
                seed: self.seed,
            },
            splits_in_info: self.splits_in_info,
            remove: self.remove_feature.clone(),
            changes: Changes {
                renames: self.rename_feature.clone(),
                set_task: self.set_task.clone(),
                task_map: self.map_tasks.clone(),
            },
            allow_reencode: self.allow_reencode,
            exact_stats: self.exact_stats,
        }
    }
}

/// Up to 20 episode indices, then how many more.
fn listed(indices: &[u64]) -> String {
    if indices.is_empty() {
        return "none".into();
    }
    let shown: Vec<String> = indices.iter().take(20).map(u64::to_string).collect();
    match indices.len() {
        n if n > 20 => format!("{} and {} more", shown.join(", "), n - 20),
        _ => shown.join(", "),
    }
}

/// `surgvla edit INPUT --out DIR`.
pub(crate) fn run_edit(args: &EditArgs) -> Result<(), CliError> {
    let planned = surgvla::export::edit::plan(&args.request())?;
    for note in &planned.chosen.notes {
        eprintln!("note: {note}");
    }
    let total = planned.steps.len();
    say!(
        "{}: keeping {} of {total} episodes; dropping {}",
        args.input.display(),
        planned.chosen.kept.len(),
        listed(&planned.chosen.dropped)
    );
    if args.dry_run {
        return dry_run(&planned, args);
    }
    if planned.outputs.len() > 1
        && !args.resume
        && std::fs::read_dir(&args.out).is_ok_and(|mut d| d.next().is_some())
    {
        return Err(CliError::usage(format!(
            "{} is not empty: give a new folder (or --resume an interrupted edit)",
            args.out.display()
        )));
    }
    let threads = args.threads.unwrap_or(0);
    for k in 0..planned.outputs.len() {
        write_output(&planned, k, args, threads)?;
    }
    Ok(())
}

/// Writes (and verifies) output `k`.
fn write_output(
    planned: &Planned,
    k: usize,
    args: &EditArgs,
    threads: usize,
) -> Result<(), CliError> {
    let output = &planned.outputs[k];
    let path = &output.path;
    let state = crate::commands::convert::Output {
        resuming: surgvla::export::resumes(path, args.resume),
        created: !path.exists(),
    };
    if args.resume && !state.resuming && surgvla::export::edit::run::is_complete(path) {
        say!("{} is complete already", path.display());
        return Ok(());
    }
    crate::interrupt::writing(path, true);
    let bar = crate::progress::episode_bar(output.order.len() as u64, "editing");
    let mut trimmed = crate::memory::Trimmer::default();
    let (summary, reencoded) = planned
        .write(k, threads, args.resume, &mut |done| {
            bar.set_position(done);
            trimmed.after_episodes(done);
        })
        .map_err(|e| state.failed(e, path))?;
    bar.finish_and_clear();
    let split = output
        .split
        .as_ref()
        .map_or(String::new(), |s| format!("split {s}: "));
    say!(
        "{split}wrote {}, {} to {} ({}, {:.1} MB)",
        crate::say::n(summary.episodes, "episode"),
        crate::say::n(summary.frames, "frame"),
        path.display(),
        crate::say::n(summary.files, "file"),
        summary.bytes as f64 / 1e6
    );
    for (episode, feature) in &reencoded {
        say!("encoded again: episode {episode}'s {feature} (it could not be copied alone)");
    }
    if args.verify {
        let differences = planned.verify(k, !reencoded.is_empty())?;
        crate::commands::convert::verified(&differences, path, &args.input.display().to_string())?;
    }
    Ok(())
}

/// `--dry-run`: each output's episodes, frames, estimated size and the episodes to encode
/// again.
fn dry_run(planned: &Planned, args: &EditArgs) -> Result<(), CliError> {
    let found = surgvla::export::edit::dry_run(planned)?;
    for output in &found.outputs {
        say!(
            "would write {}, {} to {} (about {:.1} MB); encode again: {}",
            crate::say::n(output.episodes, "episode"),
            crate::say::n(output.frames, "frame"),
            output.path.display(),
            output.estimated_bytes as f64 / 1e6,
            listed(&output.reencode)
        );
    }
    if !args.allow_reencode && found.outputs.iter().any(|o| !o.reencode.is_empty()) {
        say!("those episodes' video cannot be copied alone: the edit needs --allow-reencode");
    }
    Ok(())
}
