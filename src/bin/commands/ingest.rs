//! `surgvla ingest INPUT... --out DIR`: robot recordings (ROS 1 bags, ROS 2 MCAP files) into
//! any format surgvla writes, synchronised by the stated rule, with a report per input (the
//! library reads, plans, converts and verifies; here are the flags and the printing).

use crate::commands::convert::open_output;
use crate::error::CliError;
use crate::formats::{Format, FormatArgs};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use surgvla::export::collection::Shard;
use surgvla::export::convert::ConvertError;
use surgvla::export::{EpisodeSink, EpisodeSource, Summary};
use surgvla::ingest::dvrk::DvrkPreset;
use surgvla::ingest::openh;
use surgvla::ingest::source::{IngestOptions, IngestSource, Parting};
use surgvla::ingest::stamps::Clock;
use surgvla::ingest::sync::{OnGap, SyncOptions};

#[derive(Args, Debug)]
pub(crate) struct IngestArgs {
    /// The recordings, each read as one session in the order given: ROS 1 bags (.bag) and
    /// ROS 2 MCAP files (.mcap).
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output folder (must not exist or be empty); for RLDS the TFDS data directory.
    #[arg(long)]
    out: PathBuf,
    /// The format to write.
    #[arg(long, value_enum, default_value = "lerobot")]
    to: Format,
    /// How topics become features: dvrk (the da Vinci Research Kit's CRTK topics per arm).
    #[arg(long, value_enum, default_value = "dvrk")]
    preset: Preset,
    /// An arm's namespace, repeatable for bimanual recordings (state and action concatenated
    /// in this order): PSM1, or a full namespace such as /dvrk/PSM1 (dVRK 1.x).
    #[arg(long = "arm", default_value = "PSM1")]
    arms: Vec<String>,
    /// A camera as NAME=TOPIC, repeatable: each an image feature, observation.images.NAME
    /// (sensor_msgs/Image or CompressedImage).
    #[arg(long = "camera", required = true, value_parser = parse_camera)]
    cameras: Vec<(String, String)>,
    /// A depth camera as NAME=TOPIC, repeatable: observation.images.NAME, H x W x 1, a 16-bit
    /// PNG in millimetres (sensor_msgs/Image 16UC1 as recorded; 32FC1 metres rounded to mm).
    #[arg(long = "depth", value_parser = parse_camera)]
    depths: Vec<(String, String)>,
    /// More topics as features, a TOML file of [[feature]] tables (name, topic, kind, values
    /// = pose | joints | fields, fields, count, names): a second instrument, the ECM's pose,
    /// a force sensor as observation.meta.*; see docs/ingest.md.
    #[arg(long)]
    map: Option<PathBuf>,
    /// The task of every episode (wins over an /instruction topic in the recording).
    #[arg(long)]
    task: Option<String>,
    /// Frames per second of the dataset (the synchronisation grid).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=1000))]
    fps: u32,
    /// A sampled stream's message older than this misses the frame, ms (default 1.5 / fps).
    #[arg(long, value_parser = parse_tolerance)]
    tolerance_ms: Option<f64>,
    /// Where frames are not written: split (a new episode after the gap) or drop (one episode,
    /// frames numbered on).
    #[arg(long, value_enum, default_value = "split")]
    on_gap: GapArg,
    /// The time a message is put on the grid by: header (its header.stamp) or receive (when the
    /// recorder received it: for stamps that are zero or on another clock).
    #[arg(long, value_enum, default_value = "header")]
    clock: ClockArg,
    /// Shift a topic's times, TOPIC=MS (repeatable; negative for earlier).
    #[arg(long = "time-offset", value_parser = parse_offset)]
    offsets: Vec<(String, i64)>,
    /// Write what a contribution to a collection asks for. open-h: LeRobot 2.1 in video mode
    /// (H.264 unless --video names another codec), each frame's instruction as
    /// instruction.text, and meta/README.md from Open-H's dataset template with the
    /// synchronisation section filled from the reports.
    #[arg(long, value_enum)]
    profile: Option<Profile>,
    /// Name a range of episode indices, NAME=START:END (end excluded; repeatable), written
    /// into LeRobot's info.json splits, e.g. --split train=0:8 --split recovery=8:10 (Open-H
    /// asks for recovery and failure splits). Default: every episode is train.
    #[arg(long = "split", value_parser = parse_split)]
    splits: Vec<(String, std::ops::Range<u64>)>,
    /// Each frame's instruction as a text feature, instruction.text: the --task, else the
    /// latest /instruction message at or before the frame (on with --profile open-h).
    #[arg(long)]
    instruction_text: bool,
    /// Continue an interrupted ingest into --out (same inputs and options).
    #[arg(long)]
    resume: bool,
    /// This machine's part of the inputs, I/N (0-based): the I-th contiguous range of the
    /// inputs given, into its own complete dataset; `merge` joins the parts.
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// An episode goes to the writer in parts of about this many MiB of encoded images (LeRobot
    /// appends each part as it comes, so memory does not follow the episode's length; each is
    /// a row group of the data file): lower holds less, higher makes fewer row groups.
    #[arg(long, default_value_t = 32.0, value_parser = parse_part_mib)]
    part_mib: f64,
    /// Worker threads encoding episodes (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::app::threads_arg)]
    threads: Option<usize>,
    /// Afterwards read the recordings and the output again and compare every frame; a
    /// difference exits 1.
    #[arg(long)]
    verify: bool,
    #[command(flatten)]
    formats: FormatArgs,
}

/// How a recording's topics become features.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Preset {
    /// The da Vinci Research Kit: measured_cp + jaw/measured_js as the state, setpoint_cp +
    /// jaw/setpoint_js as the action, [x, y, z, qx, qy, qz, qw, jaw] per arm.
    Dvrk,
}

/// A collection's conventions for the output.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Profile {
    /// Open-H-Embodiment: LeRobot 2.1 video, instruction.text, meta/README.md from its
    /// template; its validator (scripts/validation/validate_formatting.py) passes it.
    OpenH,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum GapArg {
    /// A new episode after each gap: every episode continuous at --fps.
    Split,
    /// One episode per input; the written frames numbered on.
    Drop,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ClockArg {
    /// Each message's header.stamp.
    Header,
    /// The time the recorder received each message.
    Receive,
}

fn parse_camera(text: &str) -> Result<(String, String), String> {
    let (name, topic) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?} is not NAME=TOPIC"))?;
    if !surgvla::export::paths::is_plain_name(name) {
        return Err(format!(
            "camera name {name:?}: 1 to 64 letters, digits, _ and - (it names a feature)"
        ));
    }
    if !topic.starts_with('/') {
        return Err(format!("camera topic {topic:?} must start with /"));
    }
    Ok((name.to_string(), topic.to_string()))
}

fn parse_offset(text: &str) -> Result<(String, i64), String> {
    let (topic, ms) = text
        .rsplit_once('=')
        .ok_or_else(|| format!("{text:?} is not TOPIC=MS"))?;
    let ms: f64 = ms
        .parse()
        .map_err(|_| format!("{ms:?} is not a number of milliseconds"))?;
    if !ms.is_finite() || ms.abs() > 3.6e6 {
        return Err(format!("{ms} ms: an offset is at most an hour either way"));
    }
    Ok((topic.to_string(), (ms * 1e6).round() as i64))
}

fn parse_split(text: &str) -> Result<(String, std::ops::Range<u64>), String> {
    let (name, range) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?} is not NAME=START:END"))?;
    if !surgvla::export::paths::is_plain_name(name) {
        return Err(format!(
            "split name {name:?}: 1 to 64 letters, digits, _ and -"
        ));
    }
    let (start, end) = range
        .split_once(':')
        .ok_or_else(|| format!("{range:?} is not START:END (episode indices, end excluded)"))?;
    let index = |v: &str| {
        v.parse::<u64>()
            .map_err(|_| format!("{v:?} is not an episode index"))
    };
    Ok((name.to_string(), index(start)?..index(end)?))
}

fn parse_tolerance(text: &str) -> Result<f64, String> {
    let ms: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of milliseconds"))?;
    if !(ms > 0.0 && ms <= 60_000.0) {
        return Err(format!(
            "{ms} ms: the tolerance is above 0 and at most 60000"
        ));
    }
    Ok(ms)
}

fn parse_part_mib(text: &str) -> Result<f64, String> {
    let mib: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of MiB"))?;
    if !(mib > 0.0 && mib <= 65_536.0) {
        return Err(format!(
            "{mib} MiB: a part is above 0 and at most 65536 MiB"
        ));
    }
    Ok(mib)
}

impl IngestArgs {
    fn options(&self) -> Result<IngestOptions, CliError> {
        let Preset::Dvrk = self.preset;
        let mapped = match &self.map {
            Some(path) => surgvla::ingest::map::load(path)?,
            None => Vec::new(),
        };
        let mut sync = SyncOptions::at(self.fps);
        if let Some(ms) = self.tolerance_ms {
            sync.tolerance_ns = (ms * 1e6).round() as i64;
        }
        sync.on_gap = match self.on_gap {
            GapArg::Split => OnGap::Split,
            GapArg::Drop => OnGap::Drop,
        };
        Ok(IngestOptions {
            preset: DvrkPreset::new(&self.arms, &self.cameras)
                .with_depths(&self.depths)
                .with_mapped(mapped),
            clock: match self.clock {
                ClockArg::Header => Clock::Header,
                ClockArg::Receive => Clock::Receive,
            },
            sync,
            task: self.task.clone(),
            offsets_ns: self.offsets.clone(),
            instruction_text: self.instruction_text || self.profile == Some(Profile::OpenH),
            splits: self.splits.clone(),
            scratch: Some(self.out.clone()),
            parting: Parting {
                part_bytes: (self.part_mib * 1_048_576.0).ceil() as usize,
                ..Parting::default()
            },
        })
    }

    /// The inputs of this shard.
    fn inputs(&self) -> Result<&[PathBuf], CliError> {
        let range = self.shard.range(self.inputs.len());
        if range.is_empty() {
            return Err(CliError::usage(format!(
                "shard {} would hold no input: {} were given",
                self.shard,
                self.inputs.len()
            )));
        }
        for input in &self.inputs[range.clone()] {
            if !input.exists() {
                return Err(CliError::usage(format!(
                    "{} does not exist",
                    input.display()
                )));
            }
        }
        Ok(&self.inputs[range])
    }

    fn open(&self) -> Result<IngestSource, CliError> {
        let bar = crate::progress::spinner("reading the recordings' times");
        let source = IngestSource::open(self.inputs()?, self.options()?);
        bar.finish_and_clear();
        Ok(source?)
    }
}

/// `--verify`: what the output holds against the recordings.
fn verify(args: &IngestArgs, summary: &Summary) -> Result<(), CliError> {
    let mut source = args.open()?;
    let differences = surgvla::export::verify::verify_output(&mut source, &args.out, summary)?;
    crate::commands::convert::verified(&differences, &args.out, "the recordings")
}

/// `surgvla ingest INPUT... --out DIR`.
pub(crate) fn run_ingest(args: &IngestArgs) -> Result<(), CliError> {
    let options = match args.profile {
        Some(Profile::OpenH) => args.formats.open_h_options(args.to)?,
        None => args.formats.sink_options(args.to, "--to")?,
    };
    if args.profile == Some(Profile::OpenH) && !args.depths.is_empty() {
        return Err(CliError::usage(
            "--depth with --profile open-h: lerobot 0.3.3, which Open-H's validator loads with, takes image statistics of three channels only; ingest depth cameras without the profile",
        ));
    }
    if !args.splits.is_empty() && args.to.0.name() != "lerobot" {
        return Err(CliError::usage(
            "--split is written into LeRobot's info.json; --to names another format",
        ));
    }
    if !args.splits.is_empty() && args.shard.count > 1 {
        return Err(CliError::usage(
            "--split names indices of the whole dataset: give it to the ingest of all inputs, not to a --shard",
        ));
    }
    let mut source = args.open()?;
    for (path, report) in source.reports() {
        let gaps: usize = report.streams.iter().map(|s| s.gaps.len()).sum();
        eprintln!(
            "{}: {}, {}, {} not written, {}",
            path.display(),
            crate::say::n(report.episodes.len() as u64, "episode"),
            crate::say::n(report.episodes.iter().sum::<usize>() as u64, "frame"),
            crate::say::n(report.dropped_frames, "frame"),
            crate::say::n(gaps as u64, "gap")
        );
    }
    let mut files = source.sync_files(args.to.0)?;
    let info = source.info().clone();
    if args.profile == Some(Profile::OpenH) {
        let name = (args.out.file_name()).map_or("dataset".into(), |n| n.to_string_lossy());
        let reports = source.reports();
        let readme = openh::readme(&openh::ReadmeFacts {
            name: &name,
            info: &info,
            preset: &source.options().preset,
            task: args.task.as_deref(),
            reports: &reports,
        });
        files.push((openh::README_PATH.into(), readme.into_bytes()));
    }
    let (mut sink, output) = open_output(&args.out, &info, options.as_ref(), args.resume)?;
    let summary =
        write(args, &mut source, sink.as_mut(), files).map_err(|e| output.failed(e, &args.out))?;
    say!(
        "ingested {}, {} from {} into {} ({}, {:.1} MB)",
        crate::say::n(summary.episodes, "episode"),
        crate::say::n(summary.frames, "frame"),
        crate::say::n(
            args.inputs().map_or(0, <[PathBuf]>::len) as u64,
            "recording"
        ),
        args.out.display(),
        crate::say::n(summary.files, "file"),
        summary.bytes as f64 / 1e6
    );
    if args.verify {
        verify(args, &summary)?;
    }
    Ok(())
}

/// Writes every episode, then finishes with the reports beside the dataset.
fn write(
    args: &IngestArgs,
    source: &mut IngestSource,
    sink: &mut (dyn EpisodeSink + Send),
    files: Vec<(String, Vec<u8>)>,
) -> Result<Summary, ConvertError> {
    let bar = crate::progress::episode_bar(source.len(), "ingesting");
    let mut trimmed = crate::memory::Trimmer::default();
    let mut files = Some(files);
    let mut sidecar = |_: &Summary| Ok(files.take().unwrap_or_default());
    let summary = surgvla::export::convert::convert_with(
        source,
        sink,
        args.threads.unwrap_or(0),
        &mut |done| {
            bar.set_position(done);
            trimmed.after_episodes(done);
        },
        Some(&mut sidecar),
    )?;
    bar.finish_and_clear();
    Ok(summary)
}
