//! What the episode-producing commands share (`collect`, `experts`, and `eval`'s task lists):
//! [`JobArgs`], the task list and instruction choice.

use crate::error::CliError;
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use surgvla::collect::run::CollectOptions;
use surgvla::policy::ExpertLibrary;
use surgvla::task::{InstructionChoice, TaskConfig, TaskId, UnknownTasks};

/// `--tasks`: "all" or a comma-separated list of task names or ids and levels (`L1`).
#[derive(Clone, Debug)]
pub(crate) struct TaskList(pub Vec<TaskId>);

pub(crate) fn parse_tasks(text: &str) -> Result<TaskList, UnknownTasks> {
    surgvla::task::parse_task_list(text).map(TaskList)
}

/// Which instruction each episode gets.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub(crate) enum Instructions {
    /// The task's canonical instruction.
    Canonical,
    /// A seeded paraphrase.
    Paraphrase,
    /// A seeded mix of the canonical instruction and the paraphrases.
    Mixed,
    /// The detailed prompt: the target described, distractors and other sites named.
    Detailed,
    /// An instruction naming an object the scene does not hold (a language probe).
    AbsentObject,
}

impl Instructions {
    /// The library's choice.
    pub(crate) fn choice(self) -> InstructionChoice {
        match self {
            Instructions::Canonical => InstructionChoice::Canonical,
            Instructions::Paraphrase => InstructionChoice::Paraphrase,
            Instructions::Mixed => InstructionChoice::Mixed,
            Instructions::Detailed => InstructionChoice::Detailed,
            Instructions::AbsentObject => InstructionChoice::AbsentObject,
        }
    }
}

/// A feature of the default dataset to leave out.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Omit {
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
pub(crate) enum Gripper {
    /// 1 while commanded open, 0 while closed.
    Continuous,
    /// +1/-1 on the step the command changes, 0 otherwise (for ablations).
    Pulse,
}

/// What episodes to make: tasks, counts, seed, scene options, experts.
#[derive(Args, Debug)]
#[command(next_help_heading = "Episodes")]
pub(crate) struct JobArgs {
    /// Tasks: "all" or a comma-separated list of names, ids (T1-1) and levels (L1, level2: that
    /// level's tasks), mixed.
    #[arg(long, default_value = "all", value_parser = parse_tasks)]
    tasks: TaskList,
    /// Verified episodes per task.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    episodes_per_task: u64,
    /// Collection seed: every episode's seed derives from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default and 0: one per core; at most 8 per core).
    #[arg(long, value_parser = crate::app::threads_arg, help_heading = "Running")]
    pub(crate) threads: Option<usize>,
    /// Distractors in the level-2 pick tasks (T2-1, T2-2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=3))]
    pub(crate) distractors: u64,
    /// Instruction per episode: the canonical one, a seeded paraphrase, or a seeded mix.
    #[arg(long, value_enum, default_value = "canonical")]
    instructions: Instructions,
    /// Multiplies every spawn range's half width (3 gives the needle's evaluation range).
    #[arg(long, default_value_t = 1.0)]
    pub(crate) spawn_scale: f64,
    /// A folder of expert plans (*.toml) replacing the built-in scripted_policies/ per task.
    #[arg(long)]
    pub(crate) policies: Option<PathBuf>,
    /// Attempts per episode before the run gives up.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=1000))]
    max_attempts: u32,
}

impl JobArgs {
    /// The library's options (one shard, continuous gripper) and the experts.
    pub(crate) fn options(&self) -> Result<(CollectOptions, ExpertLibrary), CliError> {
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
