//! The episode-producing commands: `collect` (verified episodes into a dataset) and `experts`
//! (the experts' success rates, without rendering or writing). Both share [`JobArgs`].

use crate::UsageError;
use crate::progress;
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;
use surgvla::collect::run::{CollectOptions, Shard, collect, measure_experts};
use surgvla::episode::GripperEncoding;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotVersion, LeRobotWriter, VideoOptions};
use surgvla::policy::ExpertLibrary;
use surgvla::render::Camera;
use surgvla::task::{InstructionChoice, TaskConfig, TaskId};

/// What episodes to make: tasks, counts, seed, scene options, experts.
#[derive(Args, Debug)]
pub struct JobArgs {
    /// Tasks: "all" or a comma-separated list of names or ids.
    #[arg(long, default_value = "all")]
    tasks: String,
    /// Verified episodes per task.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    episodes_per_task: u64,
    /// Collection seed: every episode's seed derives from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Distractors in the level-2 pick tasks (T2-1, T2-2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=3))]
    distractors: u64,
    /// Instruction per episode: the canonical one, a seeded paraphrase, or a seeded mix.
    #[arg(long, default_value = "canonical", value_parser = ["canonical", "paraphrase", "mixed"])]
    instructions: String,
    /// Multiplies every spawn range's half width (3 gives the needle's evaluation range).
    #[arg(long, default_value_t = 1.0)]
    spawn_scale: f64,
    /// A folder of expert plans (*.toml) replacing the built-in scripted_policies/ per task.
    #[arg(long)]
    policies: Option<PathBuf>,
    /// Attempts per episode before the run gives up.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=1000))]
    max_attempts: u32,
}

fn usage(message: String) -> anyhow::Error {
    anyhow::Error::new(UsageError(message))
}

fn parse_tasks(text: &str) -> anyhow::Result<Vec<TaskId>> {
    if text.trim() == "all" {
        return Ok(TaskId::ALL.to_vec());
    }
    text.split(',')
        .map(|t| t.parse::<TaskId>().map_err(anyhow::Error::from))
        .collect()
}

impl JobArgs {
    /// The library's options (one shard, continuous gripper) and the experts.
    fn options(&self) -> anyhow::Result<(CollectOptions, ExpertLibrary)> {
        let tasks = parse_tasks(&self.tasks).map_err(|e| usage(e.to_string()))?;
        if !(self.spawn_scale.is_finite() && (0.0..=5.0).contains(&self.spawn_scale)) {
            return Err(usage(format!(
                "--spawn-scale {} must be between 0 and 5",
                self.spawn_scale
            )));
        }
        let library = match &self.policies {
            Some(folder) => ExpertLibrary::with_folder(folder),
            None => ExpertLibrary::builtin(),
        }
        .map_err(|e| usage(e.to_string()))?;
        let task = TaskConfig {
            distractors: self.distractors as usize,
            instruction: match self.instructions.as_str() {
                "paraphrase" => InstructionChoice::Paraphrase,
                "mixed" => InstructionChoice::Mixed,
                _ => InstructionChoice::Canonical,
            },
            spawn_scale: self.spawn_scale,
            ..TaskConfig::default()
        };
        let options = CollectOptions {
            tasks,
            episodes_per_task: self.episodes_per_task,
            seed: self.seed,
            threads: self.threads.unwrap_or(0),
            max_attempts: self.max_attempts,
            record: surgvla::collect::record::RecordOptions {
                task,
                ..Default::default()
            },
            ..CollectOptions::default()
        };
        Ok((options, library))
    }
}

#[derive(Args, Debug)]
pub struct CollectArgs {
    #[command(flatten)]
    job: JobArgs,
    /// Output folder (must not exist or be empty).
    #[arg(long, default_value = "data")]
    out: PathBuf,
    /// Output format (RLDS and point clouds are separate exporters, still to come).
    #[arg(long, default_value = "lerobot", value_parser = ["lerobot"])]
    format: String,
    /// Also store the segmentation mask as an image feature.
    #[arg(long)]
    with_mask: bool,
    /// Store the endoscope RGB as MP4 video (LeRobot video mode) instead of PNG: av1 (rav1e,
    /// LeRobot's codec family) or h264 (openh264, faster). `--video` alone means av1.
    #[arg(long, num_args = 0..=1, default_missing_value = "av1", value_parser = ["av1", "h264"])]
    video: Option<String>,
    /// This machine's part of the episode list, I/N (0-based): N machines with I = 0..N-1 each
    /// write the I-th contiguous range of episodes as their own dataset.
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// Continue an interrupted run in --out (same options and seed): episodes up to its last
    /// checkpoint are kept, the rest are recorded again.
    #[arg(long)]
    resume: bool,
    /// LeRobot layout: 3.0 (current) or 2.1 (one file per episode, JSON-lines metadata).
    #[arg(long, default_value = "3.0", value_parser = ["3.0", "2.1"])]
    lerobot_version: String,
    /// action[6]: "continuous" (1 while commanded open, 0 while closed) or "pulse" (+1/-1 on
    /// the step the command changes, 0 otherwise; for ablations).
    #[arg(long, default_value = "continuous", value_parser = ["continuous", "pulse"])]
    gripper_encoding: String,
    /// Randomise light, tissue colour and texture contrast per episode.
    #[arg(long)]
    randomize_appearance: bool,
    /// Size at which a data file is closed and a new one begun, MB (LeRobot's
    /// data_files_size_in_mb); each closed file is also a resume checkpoint.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    data_file_mb: u64,
}

pub fn run_collect(args: &CollectArgs) -> anyhow::Result<()> {
    let (mut options, library) = args.job.options()?;
    let gripper = if args.gripper_encoding == "pulse" {
        GripperEncoding::Pulse
    } else {
        GripperEncoding::Continuous
    };
    options.shard = args.shard;
    options.record.gripper = gripper;
    options.record.randomize_appearance = args.randomize_appearance;
    let job = &args.job;
    let mut metadata = surgvla::view::dataset_metadata(&Camera::endoscope());
    metadata["collection"] = serde_json::json!({
        "seed": job.seed,
        "tasks": options.tasks.iter().map(|t| t.code()).collect::<Vec<_>>(),
        "episodes_per_task": job.episodes_per_task,
        "shard": args.shard.to_string(),
        "gripper_encoding": gripper,
        "distractors": job.distractors,
        "instructions": job.instructions,
        "spawn_scale": job.spawn_scale,
        "randomize_appearance": args.randomize_appearance,
        "policies": if job.policies.is_some() { "custom" } else { "builtin" },
    });
    let writer_options = LeRobotOptions {
        with_mask: args.with_mask,
        extra_metadata: metadata,
        video: args.video.as_deref().map(|codec| match codec {
            "h264" => VideoOptions::h264(),
            _ => VideoOptions::default(),
        }),
        version: if args.lerobot_version == "2.1" {
            LeRobotVersion::V21
        } else {
            LeRobotVersion::V30
        },
        data_file_size_mb: args.data_file_mb,
        ..LeRobotOptions::default()
    };
    let interrupted = args
        .out
        .join(surgvla::export::lerobot::INCOMPLETE_MARKER)
        .exists();
    let (writer, resume_at) = if args.resume && interrupted {
        let writer = LeRobotWriter::resume(&args.out, writer_options)?;
        let next = writer.next_episode_index();
        eprintln!("resuming {} at episode {next}", args.out.display());
        (writer, next as usize)
    } else {
        (LeRobotWriter::create(&args.out, writer_options)?, 0)
    };
    let mut bars = progress::Bars::new(&options.tasks);
    let report = collect(&options, &library, Box::new(writer), resume_at, &mut bars)?;
    bars.clear();
    let path = args.out.join("collect_report.json");
    let json = serde_json::to_string_pretty(&report)?;
    surgvla::export::write_atomically(&path, json.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    progress::print_summary(&report)?;
    say!(
        "wrote {} episodes, {} frames to {} ({} files, {:.1} MB); report {}",
        report.dataset.episodes,
        report.dataset.frames,
        args.out.display(),
        report.dataset.files,
        report.dataset.bytes as f64 / 1e6,
        path.display()
    );
    Ok(())
}

#[derive(Args, Debug)]
pub struct ExpertsArgs {
    #[command(flatten)]
    job: JobArgs,
    /// Failed attempts to list (with the seed that reproduces each).
    #[arg(long, default_value_t = 10)]
    show_failures: usize,
}

/// Runs the experts as `collect` would (same attempts, replay check) without rendering or
/// writing, and prints their success rates: the quick check of a new or edited plan.
pub fn run_experts(args: &ExpertsArgs) -> anyhow::Result<()> {
    let (options, library) = args.job.options()?;
    let mut bars = progress::Bars::new(&options.tasks);
    let report = measure_experts(&options, &library, &mut bars)?;
    bars.clear();
    progress::print_expert_table(&report)?;
    let job = &args.job;
    // `surgvla sim` replays an attempt only with the built-in plans and default scene options.
    let sim_reproduces = job.policies.is_none() && job.distractors == 1 && job.spawn_scale == 1.0;
    let failures = report.failures.iter().filter(|f| f.stage != "spawn");
    for failure in failures.take(args.show_failures) {
        let code = failure.slot.task.code();
        let seed = failure.seed;
        let hint = if sim_reproduces {
            format!("surgvla sim --task {code} --seed {seed}")
        } else {
            format!("seed {seed}")
        };
        say!(
            "{code} episode {} attempt {} ({}): {}  [{hint}]",
            failure.slot.k,
            failure.attempt,
            failure.stage,
            failure.reason
        );
    }
    Ok(())
}
