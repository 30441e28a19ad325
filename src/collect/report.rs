//! The report of a collection (`collect_report.json`): per-task counts and expert success
//! rates, every failed attempt, the dataset summary and where the time went. [`Tally`]
//! accumulates it slot by slot.

use crate::collect::slot::{CollectOptions, Failure, FailureStage, SlotOutcome};
use crate::export::Summary;
use serde::Serialize;
use std::collections::BTreeMap;

/// Per-task figures of a collection.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TaskReport {
    pub code: String,
    pub name: String,
    pub level: u8,
    pub episodes: u64,
    pub frames: u64,
    /// Attempts the expert made (saved episodes plus expert and replay failures).
    pub attempts: u64,
    /// Attempts whose expert run satisfied the predicate, before replay filtering.
    pub expert_successes: u64,
    /// `expert_successes / attempts`.
    pub expert_success_rate: f64,
    /// Expert successes whose replay failed.
    pub replay_failures: u64,
}

/// Where the time went, seconds. Each stage's `_cpu_secs` is the time its code ran, summed over
/// the threads that ran it (on a machine with a core per thread, its CPU time): physics and
/// rendering on the workers; image encoding and statistics on the workers too when the sink
/// encodes apart (LeRobot), else inside the sink's batches (then wall seconds); building the
/// tables and writing the files on the writer; and the final metadata when the dataset is
/// finished.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Timing {
    pub wall_secs: f64,
    pub frames_per_sec: f64,
    pub physics_cpu_secs: f64,
    pub render_cpu_secs: f64,
    pub encode_cpu_secs: f64,
    pub stats_cpu_secs: f64,
    pub write_cpu_secs: f64,
    pub finish_cpu_secs: f64,
    /// Per task: wall seconds attributed by frames, and frames per second.
    pub tasks: BTreeMap<String, (f64, f64)>,
}

/// The machine-readable result of a collection (`collect_report.json`). Everything except
/// `timing` and `threads` is a pure function of the options.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollectReport {
    pub generator: String,
    pub seed: u64,
    pub shard: String,
    /// This shard's slots within the whole collection, `[first, end)`.
    pub slot_range: [usize; 2],
    pub episodes_per_task: u64,
    pub episodes: u64,
    pub frames: u64,
    pub tasks: Vec<TaskReport>,
    /// Every failed attempt (slot, attempt, seed, stage, reason).
    pub failures: Vec<Failure>,
    /// The episode the run resumed at, if it continued an interrupted one.
    pub resumed_at_episode: Option<u64>,
    pub dataset: Summary,
    pub threads: usize,
    pub timing: Timing,
}

/// Accumulates the report.
pub(crate) struct Tally {
    tasks: Vec<TaskReport>,
    /// Wall seconds attributed to each task (a batch's time shared by frames).
    wall_secs: Vec<f64>,
    failures: Vec<Failure>,
    physics_secs: f64,
    render_secs: f64,
}

impl Tally {
    pub(crate) fn new(options: &CollectOptions) -> Self {
        let tasks: Vec<TaskReport> = options
            .tasks
            .iter()
            .map(|t| TaskReport {
                code: t.code().into(),
                name: t.name().into(),
                level: t.level(),
                ..TaskReport::default()
            })
            .collect();
        Tally {
            wall_secs: vec![0.0; tasks.len()],
            tasks,
            failures: Vec::new(),
            physics_secs: 0.0,
            render_secs: 0.0,
        }
    }

    pub(crate) fn add(&mut self, outcome: &SlotOutcome, wall_secs: f64) {
        self.physics_secs += outcome.physics_secs;
        self.render_secs += outcome.render_secs;
        self.failures.extend(outcome.failures.iter().cloned());
        if let Some((task, wall)) = self
            .tasks
            .iter_mut()
            .zip(&mut self.wall_secs)
            .find(|(t, _)| t.code == outcome.slot.task.code())
        {
            let count = |stage| outcome.failures.iter().filter(|f| f.stage == stage).count() as u64;
            let (replay_failures, expert_failures) =
                (count(FailureStage::Replay), count(FailureStage::Expert));
            task.episodes += u64::from(outcome.verified);
            task.frames += outcome.frames;
            task.attempts += u64::from(outcome.attempts);
            task.expert_successes += u64::from(outcome.attempts) - expert_failures;
            task.replay_failures += replay_failures;
            *wall += wall_secs;
        }
    }

    pub(crate) fn finish(
        mut self,
        options: &CollectOptions,
        dataset: Summary,
        threads: usize,
        resume_at: usize,
        slot_range: [usize; 2],
        mut timing: Timing,
    ) -> CollectReport {
        for (task, wall) in self.tasks.iter_mut().zip(&self.wall_secs) {
            task.expert_success_rate = task.expert_successes as f64 / task.attempts.max(1) as f64;
            timing.tasks.insert(
                task.code.clone(),
                (*wall, task.frames as f64 / wall.max(1e-9)),
            );
        }
        let frames = self.tasks.iter().map(|t| t.frames).sum();
        timing.physics_cpu_secs = self.physics_secs;
        timing.render_cpu_secs = self.render_secs;
        timing.frames_per_sec = dataset.frames as f64 / timing.wall_secs.max(1e-9);
        CollectReport {
            generator: format!("surgvla {}", env!("CARGO_PKG_VERSION")),
            seed: options.seed,
            shard: options.shard.to_string(),
            slot_range,
            episodes_per_task: options.episodes_per_task,
            episodes: self.tasks.iter().map(|t| t.episodes).sum(),
            frames,
            tasks: self.tasks,
            failures: self.failures,
            resumed_at_episode: (resume_at > 0).then_some(resume_at as u64),
            dataset,
            threads,
            timing,
        }
    }
}
