//! `surgvla merge INPUT... --out DIR`: datasets of one format into one.

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;
use surgvla::export::dir::after_failure;
use surgvla::export::format::MergeRequest;

#[derive(Args, Debug)]
pub(crate) struct MergeArgs {
    /// The datasets to merge, all of one format: LeRobot, RLDS, zarr, PLY/PCD or MCAP folders
    /// (e.g. the outputs of `collect --shard I/N` or `convert --shard I/N`; shards are put in
    /// shard order, other datasets kept in the order given).
    #[arg(required = true, num_args = 1..)]
    inputs: Vec<PathBuf>,
    /// Output folder (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Worker threads encoding episodes (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::app::threads_arg)]
    threads: Option<usize>,
    /// Continue an interrupted merge into --out (the same inputs; zarr, point-cloud and MCAP
    /// merges start over in it).
    #[arg(long)]
    resume: bool,
    /// Recompute the pixel statistics of video features another tool wrote (whose metadata
    /// holds per-episode summaries only) from every decoded frame; without it they are combined
    /// by count, as lerobot does (a single input's statistics stay as they are).
    #[arg(long)]
    exact_stats: bool,
}

/// `surgvla merge INPUT... --out DIR`.
pub(crate) fn run_merge(args: &MergeArgs) -> Result<(), CliError> {
    let created = !args.out.exists();
    crate::interrupt::writing(&args.out, true);
    let bar = crate::progress::episode_bar(0, "merging");
    let threads = args.threads.unwrap_or(0);
    let summary = surgvla::export::merge(&mut MergeRequest {
        inputs: &args.inputs,
        out: &args.out,
        threads,
        resume: args.resume,
        exact_stats: args.exact_stats,
        progress: &mut |done| {
            bar.set_length(done);
            bar.set_position(done)
        },
    })
    .map_err(|e| {
        let usage = surgvla::error::HasKind::kind(&e) == surgvla::error::ErrorKind::Usage;
        let write = matches!(&e, surgvla::export::MergeError::Convert(c) if c.is_output_io());
        let resumable = after_failure(&args.out, created, args.resume, usage, write);
        CliError::from(e).resumable(resumable)
    })?;
    bar.finish_and_clear();
    say!(
        "merged {}: {}, {} into {} ({}, {:.1} MB)",
        crate::say::n(args.inputs.len() as u64, "dataset"),
        crate::say::n(summary.episodes, "episode"),
        crate::say::n(summary.frames, "frame"),
        args.out.display(),
        crate::say::n(summary.files, "file"),
        summary.bytes as f64 / 1e6
    );
    Ok(())
}
