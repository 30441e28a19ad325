//! What a collection is made of: its options, the slots (the `k`-th episode of a task), how a
//! collection is split into shards, and what happened at a slot. Both the run ([`super::run`])
//! and its report ([`super::report`]) speak these types.

use crate::collect::record::RecordOptions;
use crate::episode::Episode;
pub use crate::export::collection::{BadShard, Shard};
use crate::task::TaskId;
use serde::Serialize;

/// One episode slot: the `k`-th episode of `task`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Slot {
    #[serde(serialize_with = "task_code")]
    pub task: TaskId,
    pub k: u64,
}

fn task_code<S: serde::Serializer>(task: &TaskId, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(task.code())
}

/// Everything a collection depends on.
#[derive(Clone, Debug, PartialEq)]
pub struct CollectOptions {
    pub tasks: Vec<TaskId>,
    pub episodes_per_task: u64,
    pub seed: u64,
    pub shard: Shard,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Most attempts per slot before the collection fails.
    pub max_attempts: u32,
    pub record: RecordOptions,
}

impl Default for CollectOptions {
    fn default() -> Self {
        CollectOptions {
            tasks: TaskId::ALL.to_vec(),
            episodes_per_task: 100,
            seed: 0,
            shard: Shard::default(),
            threads: 0,
            max_attempts: 20,
            record: RecordOptions::default(),
        }
    }
}

/// Collection options that cannot make a run (the user's to fix).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct BadOptions(pub String);

/// Worker threads allowed per core: more only add memory (each worker holds a simulator and a
/// renderer, about 45 MB) and no speed.
pub const MAX_THREADS_PER_CORE: usize = 8;

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

impl CollectOptions {
    /// Refuses options that cannot make a sensible run, before anything is written: a task
    /// listed twice (its episodes would be written twice), more than [`MAX_THREADS_PER_CORE`]
    /// threads per core, a shard that would hold no episode.
    pub fn check(&self) -> Result<(), BadOptions> {
        for (i, task) in self.tasks.iter().enumerate() {
            if self.tasks[..i].contains(task) {
                return Err(BadOptions(format!(
                    "task {} ({}) is listed twice; list each task once",
                    task.code(),
                    task.name()
                )));
            }
        }
        let max = MAX_THREADS_PER_CORE * cores();
        if self.threads > max {
            return Err(BadOptions(format!(
                "{} threads: at most {max} on this machine ({MAX_THREADS_PER_CORE} per core; each \
                 worker holds a simulator and a renderer)",
                self.threads
            )));
        }
        let total = self.tasks.len() as u64 * self.episodes_per_task;
        let range = self.shard.range(total as usize);
        if range.is_empty() {
            return Err(BadOptions(format!(
                "shard {} would hold no episode: the run has {total} in all; use at most {total} shards",
                self.shard
            )));
        }
        Ok(())
    }

    /// Every slot of the collection, in order (all shards).
    pub fn all_slots(&self) -> Vec<Slot> {
        self.tasks
            .iter()
            .flat_map(|&task| (0..self.episodes_per_task).map(move |k| Slot { task, k }))
            .collect()
    }

    /// This shard's slots, in order; the dataset's episode `i` is the `i`-th of them.
    pub fn slots(&self) -> Vec<Slot> {
        let all = self.all_slots();
        let range = self.shard.range(all.len());
        all[range].to_vec()
    }
}

/// One failed attempt, with what it takes to reproduce it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Failure {
    #[serde(flatten)]
    pub slot: Slot,
    pub attempt: u32,
    pub seed: u64,
    /// Where the attempt failed.
    pub stage: FailureStage,
    pub reason: String,
}

/// Where an attempt failed (serialised as "spawn", "expert", "replay").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FailureStage {
    /// No valid scene for this seed (not counted as an attempt).
    Spawn,
    /// The predicate failed after the expert's run.
    Expert,
    /// The expert succeeded but replaying its dataset actions did not.
    Replay,
}

impl FailureStage {
    /// The stage as reports write it.
    pub fn name(self) -> &'static str {
        match self {
            FailureStage::Spawn => "spawn",
            FailureStage::Expert => "expert",
            FailureStage::Replay => "replay",
        }
    }

    /// Whether the attempt counts (a scene was made for it).
    pub fn is_attempt(self) -> bool {
        self != FailureStage::Spawn
    }
}

impl std::fmt::Display for FailureStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What happened at one slot.
#[derive(Clone, Debug, PartialEq)]
pub struct SlotOutcome {
    pub slot: Slot,
    /// An attempt passed both checks (false when all `max_attempts` failed).
    pub verified: bool,
    /// The verified episode (None when only counting).
    pub episode: Option<Episode>,
    pub frames: u64,
    pub attempts: u32,
    pub failures: Vec<Failure>,
    pub physics_secs: f64,
    pub render_secs: f64,
}
