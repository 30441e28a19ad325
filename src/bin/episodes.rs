//! The episode-producing commands: `collect` (verified episodes into a dataset) and `experts`
//! (the experts' success rates, without rendering or writing). Both share [`JobArgs`].

use crate::error::CliError;
use crate::formats::{Format, FormatArgs};
use crate::progress;
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use surgvla::collect::run::{CollectOptions, Shard, collect, dataset_info, measure_experts};
use surgvla::episode::{FeatureSet, GripperEncoding};
use surgvla::export::{open_sink, resumes};
use surgvla::policy::ExpertLibrary;
use surgvla::task::{InstructionChoice, TaskConfig, TaskId, UnknownTask};

/// `--tasks`: "all" or a comma-separated list of names or ids.
#[derive(Clone, Debug)]
pub struct TaskList(pub Vec<TaskId>);

pub fn parse_tasks(text: &str) -> Result<TaskList, UnknownTask> {
    if text.trim() == "all" {
        return Ok(TaskList(TaskId::ALL.to_vec()));
    }
    text.split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map(TaskList)
}

/// Which instruction each episode gets.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum Instructions {
    /// The task's canonical instruction.
    Canonical,
    /// A seeded paraphrase.
    Paraphrase,
    /// A seeded mix of the canonical instruction and the paraphrases.
    Mixed,
}

impl Instructions {
    /// The library's choice.
    pub fn choice(self) -> InstructionChoice {
        match self {
            Instructions::Canonical => InstructionChoice::Canonical,
            Instructions::Paraphrase => InstructionChoice::Paraphrase,
            Instructions::Mixed => InstructionChoice::Mixed,
        }
    }
}

/// A feature of the default dataset to leave out.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Omit {
    /// `observation.images.depth`: lerobot-train feeds every image feature to the policy, and
    /// ACT and Diffusion need 3-channel images of one shape.
    Depth,
    /// `observation.environment_state`: ground-truth object poses, privileged information a
    /// vision policy must not see.
    #[value(name = "environment_state")]
    EnvironmentState,
}

/// How action[6] (the gripper) is written.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum Gripper {
    /// 1 while commanded open, 0 while closed.
    Continuous,
    /// +1/-1 on the step the command changes, 0 otherwise (for ablations).
    Pulse,
}

/// What episodes to make: tasks, counts, seed, scene options, experts.
#[derive(Args, Debug)]
pub struct JobArgs {
    /// Tasks: "all" or a comma-separated list of names or ids.
    #[arg(long, default_value = "all", value_parser = parse_tasks)]
    tasks: TaskList,
    /// Verified episodes per task.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    episodes_per_task: u64,
    /// Collection seed: every episode's seed derives from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::threads_arg)]
    pub(crate) threads: Option<usize>,
    /// Distractors in the level-2 pick tasks (T2-1, T2-2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=3))]
    distractors: u64,
    /// Instruction per episode: the canonical one, a seeded paraphrase, or a seeded mix.
    #[arg(long, value_enum, default_value = "canonical")]
    instructions: Instructions,
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

impl JobArgs {
    /// The library's options (one shard, continuous gripper) and the experts.
    fn options(&self) -> Result<(CollectOptions, ExpertLibrary), CliError> {
        if !(self.spawn_scale.is_finite() && (0.0..=5.0).contains(&self.spawn_scale)) {
            return Err(CliError::usage(format!(
                "--spawn-scale {} must be between 0 and 5",
                self.spawn_scale
            )));
        }
        let library = match &self.policies {
            Some(folder) => ExpertLibrary::with_folder(folder).map_err(|e| {
                CliError::from(e).context(format!(
                    "loading the plans of --policies {}",
                    folder.display()
                ))
            })?,
            None => ExpertLibrary::builtin()?,
        };
        let task = TaskConfig {
            distractors: self.distractors as usize,
            instruction: self.instructions.choice(),
            spawn_scale: self.spawn_scale,
            ..TaskConfig::default()
        };
        let options = CollectOptions {
            tasks: self.tasks.0.clone(),
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
    pub(crate) job: JobArgs,
    /// Output folder (must not exist or be empty).
    #[arg(long, default_value = "data")]
    out: PathBuf,
    /// Output format (each has its own options below).
    #[arg(long, value_enum, default_value = "lerobot")]
    format: Format,
    /// Also store the segmentation mask as an image feature (another 1-channel image).
    #[arg(long)]
    with_mask: bool,
    /// Leave features of the default dataset out, comma-separated: `depth`, `environment_state`.
    /// Training with lerobot-train: `--without depth,environment_state` (docs/training.md, "Train a
    /// policy").
    #[arg(long, value_enum, value_delimiter = ',')]
    without: Vec<Omit>,
    /// This machine's part of the episode list, I/N (0-based): N machines with I = 0..N-1 each
    /// write the I-th contiguous range of episodes as their own dataset.
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// Continue an interrupted run in --out (same options and seed): episodes up to its last
    /// checkpoint are kept, the rest are recorded again.
    #[arg(long)]
    resume: bool,
    /// action[6]: "continuous" (1 while commanded open, 0 while closed) or "pulse" (+1/-1 on
    /// the step the command changes, 0 otherwise; for ablations).
    #[arg(long, value_enum, default_value = "continuous")]
    gripper_encoding: Gripper,
    /// Randomise light, tissue colour and texture contrast per episode.
    #[arg(long)]
    randomize_appearance: bool,
    #[command(flatten)]
    formats: FormatArgs,
}

pub fn run_collect(args: &CollectArgs) -> Result<(), CliError> {
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
    let sink_options = args.formats.sink_options(args.format, "--format")?;
    let info = dataset_info(&options, features, &library);
    let resuming = resumes(&args.out, args.resume);
    let mut sink = open_sink(&args.out, &info, sink_options.as_ref(), args.resume)?;
    if resuming {
        let next = sink.next_episode_index();
        eprintln!("resuming {} at episode {next}", args.out.display());
    }
    let mut bars = progress::Bars::new(&options.tasks);
    let report = collect(&options, &library, sink.as_mut(), &mut bars).map_err(|e| {
        let resumable = surgvla::export::DatasetDir::is_interrupted(&args.out);
        CliError::from(e).resumable(resumable)
    })?;
    bars.clear();
    let path = args.out.join(surgvla::collect::run::REPORT);
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
pub fn run_experts(args: &ExpertsArgs) -> Result<(), CliError> {
    let (options, library) = args.job.options()?;
    options.check().map_err(CliError::usage)?;
    let mut bars = progress::Bars::new(&options.tasks);
    let report = measure_experts(&options, &library, &mut bars)?;
    bars.clear();
    progress::print_expert_table(&report)?;
    let job = &args.job;
    // `surgvla sim` replays an attempt only with the built-in plans and default scene options.
    let sim_reproduces = job.policies.is_none() && job.distractors == 1 && job.spawn_scale == 1.0;
    let failures = report.failures.iter().filter(|f| f.stage.is_attempt());
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
