//! `surgvla convert INPUT --to FORMAT --out DIR`: any dataset surgvla reads into any format it
//! writes (the library reads, converts, verifies and cleans up; here are the flags and the
//! printing).

use crate::error::CliError;
use crate::formats::Format;
use crate::formats::FormatArgs;
use clap::Args;
use std::path::{Path, PathBuf};
use surgvla::export::convert::ConvertError;
use surgvla::export::dir::after_failure;
use surgvla::export::open::ConvertInput;
use surgvla::export::{EpisodeSink, SinkOptions, open_sink, resumes};

#[derive(Args, Debug)]
pub(crate) struct ConvertArgs {
    /// The dataset to read: LeRobot (v3.0 or v2.1, image or video mode) or RLDS (a TFDS data directory
    /// or its <name>/<version> folder).
    input: PathBuf,
    /// The format to write.
    #[arg(long, value_enum)]
    to: Format,
    /// Output folder (must not exist or be empty); for RLDS the TFDS data directory.
    #[arg(long)]
    out: PathBuf,
    /// Continue an interrupted conversion into --out (same input and options).
    #[arg(long)]
    resume: bool,
    /// This machine's part of the input's episodes, I/N (0-based): N machines with I = 0..N-1
    /// each convert the I-th contiguous range into its own complete dataset; `merge` joins them
    /// into what one conversion writes (Slurm: $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT).
    #[arg(long, default_value = "0/1")]
    shard: surgvla::export::collection::Shard,
    /// Worker threads encoding episodes (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::app::threads_arg)]
    threads: Option<usize>,
    #[command(flatten)]
    unstated: Unstated,
    /// Leave features out, comma-separated: depth, mask, environment_state (surgvla's optional
    /// features) or any feature key of the input (e.g. observation.images.depth of another
    /// tool's dataset), checked against its features before anything is written.
    #[arg(long, value_delimiter = ',')]
    without: Vec<String>,
    /// For an RLDS dataset another tool wrote: a TOML file naming the keys that make `action`,
    /// `observation.state`, the `task` or any other feature, in place of the Open
    /// X-Embodiment conventions surgvla finds by itself (the format of `ingest --map`, with
    /// `keys = [...]`; see docs/datasets.md).
    #[arg(long, value_name = "FILE.toml")]
    map: Option<PathBuf>,
    /// Read another tool's float64 vectors as this type (without --cast they stay float64,
    /// except in RLDS, whose TFRecord files store float32).
    #[arg(long, value_enum)]
    cast: Option<Cast>,
    /// Decode video features to pixels: with --to lerobot, write image mode (PNG) instead of
    /// copying the video as it is. Implied for every other target, and for --video with
    /// another codec than the input's (re-encoding).
    #[arg(long)]
    decode: bool,
    /// Afterwards read both sides and compare every frame (LeRobot and RLDS targets; for zarr
    /// and MCAP the output is validated and its episodes and frames counted, for PLY/PCD its
    /// files counted); a difference exits 1.
    #[arg(long)]
    verify: bool,
    /// For zarr, MCAP, PLY and PCD from another tool's dataset: the RGB image feature that is
    /// their camera (e.g. observation.images.image); its other features are carried where the
    /// format has a place for them, else left out with a note.
    #[arg(long, value_name = "KEY")]
    camera: Option<String>,
    /// With --camera: the depth image feature (16-bit grey, or float in metres) the point
    /// clouds are made of.
    #[arg(long, value_name = "KEY", requires = "camera")]
    depth: Option<String>,
    /// Metres per unit of a 16-bit --depth image [default: 0.001, millimetres].
    #[arg(long, value_name = "METRES", requires = "depth")]
    depth_unit_m: Option<f64>,
    /// With --camera: its pinhole intrinsics in pixels, FX,FY,CX,CY as OpenCV's camera matrix
    /// holds them (pixel centres at integers; point clouds need them).
    #[arg(long, value_name = "FX,FY,CX,CY", value_parser = parse_intrinsics, requires = "camera")]
    intrinsics: Option<[f64; 4]>,
    #[command(flatten)]
    formats: FormatArgs,
}

/// What an input may not state (another tool's RLDS dataset): `convert` and `edit` take it.
#[derive(Args, Debug)]
pub(crate) struct Unstated {
    /// Steps per second of an input that stores none (an RLDS dataset another tool wrote).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    fps: Option<u32>,
    /// The robot type of an input that states none (default "unknown").
    #[arg(long)]
    robot_type: Option<String>,
}

impl Unstated {
    /// The reader's options with these values.
    pub(crate) fn source_options(&self) -> surgvla::export::SourceOptions {
        surgvla::export::SourceOptions {
            fps: self.fps,
            robot_type: self.robot_type.clone(),
            ..Default::default()
        }
    }
}

/// `--intrinsics FX,FY,CX,CY`: four numbers, focal lengths positive.
fn parse_intrinsics(text: &str) -> Result<[f64; 4], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|e| format!("{v:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match values[..] {
        [fx, fy, cx, cy] if fx > 0.0 && fy > 0.0 && cx.is_finite() && cy.is_finite() => {
            Ok([fx, fy, cx, cy])
        }
        _ => Err("four numbers FX,FY,CX,CY in pixels, FX and FY positive".into()),
    }
}

/// What `--cast` narrows float64 features to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Cast {
    /// float32, about 7 significant digits.
    Float32,
}

impl ConvertArgs {
    /// What the conversion reads.
    fn input(&self) -> Result<ConvertInput, CliError> {
        let map = match &self.map {
            Some(path) => surgvla::ingest::map::load_keys(path)?,
            None => Vec::new(),
        };
        Ok(ConvertInput {
            path: self.input.clone(),
            source: surgvla::export::SourceOptions {
                map,
                float64_as_float32: self.cast == Some(Cast::Float32),
                // ConvertInput::open gives the reader the --without list.
                without: Vec::new(),
                ..self.unstated.source_options()
            },
            shard: self.shard,
            without: self.without.clone(),
            decode: self.decode,
            roles: surgvla::export::roles::Roles {
                camera: self.camera.clone(),
                depth: self.depth.clone(),
                depth_unit_m: self.depth_unit_m,
                intrinsics_px: self.intrinsics,
            },
        })
    }
}

/// `--verify`: what the output holds against the input.
fn verify(
    args: &ConvertArgs,
    options: &dyn SinkOptions,
    summary: &surgvla::export::Summary,
) -> Result<(), CliError> {
    let mut source = args.input()?.open(options)?;
    let differences = surgvla::export::verify::verify_output(source.as_mut(), &args.out, summary)?;
    verified(&differences, &args.out, &args.input.display().to_string())
}

/// Prints `--verify`'s outcome: any difference is invalid data, naming `out` and `input`.
pub(crate) fn verified(differences: &[String], out: &Path, input: &str) -> Result<(), CliError> {
    if differences.is_empty() {
        say!("verified: the output holds what was read");
        return Ok(());
    }
    for difference in differences {
        say!("difference: {difference}");
    }
    Err(CliError::invalid(format!(
        "{} does not hold what {input} holds ({} differences)",
        out.display(),
        differences.len()
    )))
}

/// The output of a conversion (or ingest) of `info` into `out`, started or resumed, saying
/// where a resume starts; with whether `out` was made here and whether it resumes.
pub(crate) fn open_output(
    out: &Path,
    info: &surgvla::export::DatasetInfo,
    options: &dyn SinkOptions,
    resume: bool,
) -> Result<(Box<dyn EpisodeSink + Send>, Output), CliError> {
    let output = Output {
        resuming: resumes(out, resume),
        created: !out.exists(),
    };
    // Said before the folder exists: an interruption in between must still name `--resume`.
    crate::interrupt::writing(out, true);
    let sink = open_sink(out, info, options, resume)?;
    if output.resuming {
        eprintln!(
            "resuming {} at episode {}",
            out.display(),
            sink.next_episode_index()
        );
    }
    Ok((sink, output))
}

/// How an output was opened: what a failure leaves of it depends on it.
#[derive(Clone, Copy)]
pub(crate) struct Output {
    pub resuming: bool,
    pub created: bool,
}

impl Output {
    /// The error of a failed conversion into `out`, saying whether `--resume` continues it.
    pub(crate) fn failed(self, error: ConvertError, out: &Path) -> CliError {
        let usage = surgvla::error::HasKind::kind(&error) == surgvla::error::ErrorKind::Usage;
        let write = error.is_output_io();
        let resumable = after_failure(out, self.created, self.resuming, usage, write);
        CliError::from(error).resumable(resumable)
    }
}

/// `surgvla convert INPUT --to FORMAT --out DIR`.
pub(crate) fn run_convert(args: &ConvertArgs) -> Result<(), CliError> {
    let options = args.formats.sink_options(args.to, "--to")?;
    let mut source = args.input()?.open(options.as_ref())?;
    let info = source.info().clone();
    for note in &info.notes {
        eprintln!("{}: {note}", args.input.display());
    }
    let (mut sink, output) = open_output(&args.out, &info, options.as_ref(), args.resume)?;
    let bar = crate::progress::episode_bar(source.len(), "converting");
    let threads = args.threads.unwrap_or(0);
    let mut trimmed = crate::memory::Trimmer::default();
    let summary =
        surgvla::export::convert::convert(source.as_mut(), sink.as_mut(), threads, &mut |done| {
            bar.set_position(done);
            trimmed.after_episodes(done);
        })
        .map_err(|e| output.failed(e, &args.out))?;
    bar.finish_and_clear();
    say!(
        "converted {}, {} from {} to {} ({}, {:.1} MB)",
        crate::say::n(summary.episodes, "episode"),
        crate::say::n(summary.frames, "frame"),
        args.input.display(),
        args.out.display(),
        crate::say::n(summary.files, "file"),
        summary.bytes as f64 / 1e6
    );
    if args.verify {
        verify(args, options.as_ref(), &summary)?;
    }
    Ok(())
}
