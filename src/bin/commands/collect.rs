//! `surgvla collect`: verified expert episodes of the tasks into a dataset of any format,
//! resumable and shardable.

use crate::error::CliError;
use crate::formats::{Format, FormatArgs};
use crate::job::Gripper;
use crate::job::JobArgs;
use crate::job::Omit;
use crate::progress;
use clap::Args;
use std::path::PathBuf;
use surgvla::collect::run::{Shard, collect, dataset_info};
use surgvla::episode::{FeatureSet, GripperEncoding};
use surgvla::export::{open_sink, resumes};

#[derive(Args, Debug)]
pub(crate) struct CollectArgs {
    #[command(flatten)]
    pub(crate) job: JobArgs,
    /// Output folder (must not exist or be empty).
    #[arg(long, default_value = "data", help_heading = "Output")]
    out: PathBuf,
    /// Output format (each has its own options below).
    #[arg(long, value_enum, default_value = "lerobot", help_heading = "Output")]
    format: Format,
    /// Also store the segmentation mask as an image feature (another 1-channel image).
    #[arg(long, help_heading = "Output")]
    with_mask: bool,
    /// Leave features of the default dataset out, comma-separated: `depth`, `environment_state`.
    /// Training with lerobot-train: `--without depth,environment_state` (docs/training.md, "Train a
    /// policy").
    #[arg(long, value_enum, value_delimiter = ',', help_heading = "Output")]
    without: Vec<Omit>,
    /// This machine's part of the episode list, I/N (0-based): N machines with I = 0..N-1 each
    /// write the I-th contiguous range of episodes as their own dataset.
    #[arg(long, default_value = "0/1", help_heading = "Running")]
    shard: Shard,
    /// Continue an interrupted run in --out (same options and seed): episodes up to its last
    /// checkpoint are kept, the rest are recorded again.
    #[arg(long, help_heading = "Running")]
    resume: bool,
    /// action[6]: "continuous" (1 while commanded open, 0 while closed) or "pulse" (+1/-1 on
    /// the step the command changes, 0 otherwise; for ablations).
    #[arg(
        long,
        value_enum,
        default_value = "continuous",
        help_heading = "Episodes"
    )]
    gripper_encoding: Gripper,
    /// Randomise light, tissue colour and texture contrast per episode.
    #[arg(long, help_heading = "Episodes")]
    randomize_appearance: bool,
    /// Write one dataset per level of the tasks, as the reference releases its data (and
    /// trains a model per level): OUT/level1, OUT/level2, OUT/level3, each complete with its
    /// card and manifest and equal to `collect --tasks L<N>` into it.
    #[arg(long, help_heading = "Output")]
    per_level: bool,
    #[command(flatten)]
    formats: FormatArgs,
}

pub(crate) fn run_collect(args: &CollectArgs) -> Result<(), CliError> {
    let (mut options, library) = args.job.options()?;
    options.shard = args.shard;
    options.record.gripper = match args.gripper_encoding {
        Gripper::Continuous => GripperEncoding::Continuous,
        Gripper::Pulse => GripperEncoding::Pulse,
    };
    options.record.randomize_appearance = args.randomize_appearance;
    // Point clouds (PLY, PCD, MCAP, zarr) carry the mask ids of their points when the frames
    // have them; LeRobot and RLDS store the mask only as its feature.
    options.record.render.mask = args.with_mask || args.format.0.capabilities().point_clouds;
    let features = FeatureSet {
        mask: args.with_mask,
        depth: !args.without.contains(&Omit::Depth),
        environment_state: !args.without.contains(&Omit::EnvironmentState),
    };
    options.check().map_err(CliError::usage)?;
    if !args.per_level {
        return collect_into(args, &options, &library, features, &args.out);
    }
    let mut levels: Vec<u8> = options.tasks.iter().map(|t| t.level()).collect();
    levels.sort_unstable();
    levels.dedup();
    for level in levels {
        let out = args.out.join(format!("level{level}"));
        let mut part = options.clone();
        part.tasks.retain(|t| t.level() == level);
        if args.resume && surgvla::export::edit::run::is_complete(&out) {
            say!("{} is complete already", out.display());
            continue;
        }
        collect_into(args, &part, &library, features, &out)?;
    }
    Ok(())
}

/// Collects `options`' episodes into a dataset at `out`, started or resumed.
fn collect_into(
    args: &CollectArgs,
    options: &surgvla::collect::run::CollectOptions,
    library: &surgvla::policy::ExpertLibrary,
    features: FeatureSet,
    out: &std::path::Path,
) -> Result<(), CliError> {
    let sink_options = args.formats.sink_options(args.format, "--format")?;
    let info = dataset_info(options, features, library);
    let resuming = resumes(out, args.resume);
    // Said before the folder exists: an interruption in between must still name `--resume`.
    crate::interrupt::writing(out, true);
    let mut sink = open_sink(out, &info, sink_options.as_ref(), args.resume)?;
    if resuming {
        let next = sink.next_episode_index();
        eprintln!("resuming {} at episode {next}", out.display());
    }
    let mut bars = progress::Bars::new(&options.tasks);
    let report = collect(options, library, sink.as_mut(), &mut bars).map_err(|e| {
        let resumable = surgvla::export::DatasetDir::is_interrupted(out);
        CliError::from(e).resumable(resumable)
    })?;
    bars.clear();
    let path = out.join(surgvla::collect::run::REPORT);
    progress::print_summary(&report)?;
    say!(
        "wrote {}, {} to {} ({}, {:.1} MB); report {}",
        crate::say::n(report.dataset.episodes, "episode"),
        crate::say::n(report.dataset.frames, "frame"),
        out.display(),
        crate::say::n(report.dataset.files, "file"),
        report.dataset.bytes as f64 / 1e6,
        path.display()
    );
    Ok(())
}
