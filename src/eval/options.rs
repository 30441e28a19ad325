//! What an evaluation is asked to do: [`EvalOptions`] (tasks, trials, policy, step limits,
//! instructions), which policy answers ([`PolicyChoice`]), and what can go wrong ([`EvalError`]).

use super::agents::SendExtras;
use crate::error::ErrorKind;
use crate::render::Camera;
use crate::task::{InstructionChoice, TaskConfig, TaskId};
use std::path::PathBuf;
use std::time::Duration;

/// The policy to evaluate.
#[derive(Clone, Debug, PartialEq)]
pub enum PolicyChoice {
    /// A policy server speaking openpi's protocol at `ws://HOST:PORT`.
    Remote { url: String },
    /// The task's scripted expert.
    Expert,
    /// The actions of the nearest training episode of the dataset at `dataset`.
    Replay { dataset: PathBuf },
    /// Seeded uniform random commands.
    Random,
    /// Zero deltas, jaws open.
    Noop,
}

impl PolicyChoice {
    /// The name results give the policy ("expert", "ws://host:8000", ...).
    pub fn name(&self) -> String {
        match self {
            PolicyChoice::Remote { url } => url.clone(),
            PolicyChoice::Expert => "expert".into(),
            PolicyChoice::Replay { .. } => "replay".into(),
            PolicyChoice::Random => "random".into(),
            PolicyChoice::Noop => "noop".into(),
        }
    }
}

/// How an evaluation runs.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalOptions {
    pub tasks: Vec<TaskId>,
    /// Trials per task.
    pub trials: u32,
    /// Every trial's seed derives from it ([`crate::eval::run::trial_seed`]).
    pub seed: u64,
    pub instruction: InstructionChoice,
    /// Distractors in T2-1 and T2-2.
    pub distractors: usize,
    /// Spawn-range scale for every task; None: the reference's evaluation ranges
    /// ([`evaluation_spawn_scale`]).
    pub spawn_scale: Option<f64>,
    /// What a remote policy is sent beyond image, state and prompt.
    pub send: SendExtras,
    /// Actions of a remote chunk executed before asking again (None: the whole chunk).
    pub replan_steps: Option<usize>,
    /// Bound on connecting to a remote policy and on each of its replies.
    pub timeout: Duration,
    /// Worker threads for the built-in policies (a remote policy runs one trial at a time).
    pub threads: usize,
    /// Failed trials per task recorded as MCAP in `out/failures/`.
    pub recordings_per_task: usize,
    /// The results folder: new or empty, or holding an earlier run's results when `replace`.
    pub out: PathBuf,
    /// Replace an earlier run's results in `out` (never other files).
    pub replace: bool,
    /// Continue an interrupted run of the same evaluation in `out` from the trials its
    /// journal holds.
    pub resume: bool,
    /// The policy's name in the results, tables and charts (None: a served policy's own, from
    /// its metadata, else its URL; a built-in policy's name).
    pub name: Option<String>,
    pub camera: Camera,
    /// The variants to run each task's trials under, in order (None: the unperturbed trials
    /// only); each variant's trials share the unperturbed ones' seeds.
    pub suite: Option<super::perturb::Suite>,
    /// Render every observation for the built-in policies too (they read the simulator's state,
    /// so this only costs time: what a served policy's evaluation renders, for benchmarks).
    pub render_builtin: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            tasks: TaskId::ALL.to_vec(),
            trials: 50,
            seed: 0,
            instruction: InstructionChoice::Canonical,
            distractors: 1,
            spawn_scale: None,
            send: SendExtras::default(),
            replan_steps: None,
            timeout: Duration::from_secs(30),
            threads: 1,
            recordings_per_task: 3,
            out: PathBuf::from("eval"),
            replace: false,
            resume: false,
            name: None,
            camera: Camera::endoscope(),
            suite: None,
            render_builtin: false,
        }
    }
}

/// The reference's evaluation spawn ranges as a scale of the collection's: the needle spawns
/// within +-0.03 m instead of +-0.01 m (T1-2, `tasks.md`); every other task as collected.
pub fn evaluation_spawn_scale(task: TaskId) -> f64 {
    if task == TaskId::NeedlePick { 3.0 } else { 1.0 }
}

/// A policy's name as results label it (given with `--policy-name` or served in a policy
/// server's metadata): trimmed, 1 to 64 characters, no control character; None otherwise.
pub fn policy_label(text: &str) -> Option<String> {
    let name = text.trim();
    (!name.is_empty() && name.chars().count() <= 64 && !name.contains(char::is_control))
        .then(|| name.to_string())
}

impl EvalOptions {
    /// The variants each task runs under (the unperturbed one alone without a suite).
    pub fn variants(&self) -> Vec<super::perturb::Variant> {
        match &self.suite {
            Some(suite) => suite.variants.clone(),
            None => vec![super::perturb::Variant::default()],
        }
    }

    /// The scene options of `task`'s trials.
    pub fn task_config(&self, task: TaskId) -> TaskConfig {
        TaskConfig {
            distractors: self.distractors,
            instruction: self.instruction,
            spawn_scale: self
                .spawn_scale
                .unwrap_or_else(|| evaluation_spawn_scale(task)),
            ..TaskConfig::default()
        }
    }
}

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("the policy server could not be reached")]
    Unreachable(#[source] super::remote::RemoteError),
    #[error("reading the replay dataset {path}")]
    ReplayDataset {
        path: PathBuf,
        #[source]
        source: crate::export::ExportError,
    },
    #[error("the replay dataset {path} has no episode of {task}")]
    NoDemonstration { path: PathBuf, task: TaskId },
    #[error(transparent)]
    Spawn(#[from] crate::task::SpawnError),
    #[error(transparent)]
    Plan(#[from] crate::policy::PlanError),
    #[error("{0}")]
    Options(String),
    #[error("writing {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: crate::export::ExportError,
    },
}

impl crate::error::HasKind for EvalError {
    /// Exit 2 for what the user gave (an unreachable server at start, an unusable option, a
    /// replay dataset that is not there), 1 when writing the results failed or the replay
    /// dataset is invalid (as every command judges a dataset).
    fn kind(&self) -> ErrorKind {
        match self {
            EvalError::Write { source, .. } | EvalError::ReplayDataset { source, .. } => {
                source.kind()
            }
            EvalError::Plan(e) => e.kind(),
            EvalError::Spawn(_) => ErrorKind::Failed,
            _ => ErrorKind::Usage,
        }
    }

    /// Writing the results failed because the disk is full.
    fn is_disk_full(&self) -> bool {
        matches!(self, EvalError::Write { source, .. } if source.is_disk_full())
    }
}

#[cfg(test)]
mod tests {
    use super::policy_label;

    #[test]
    fn a_policy_label_is_short_trimmed_text() {
        assert_eq!(policy_label("  pi0-fast \n").as_deref(), Some("pi0-fast"));
        assert_eq!(policy_label(&"é".repeat(64)).map(|n| n.len()), Some(128));
        for refused in ["", "   ", "a\u{7}b", "two\nlines", &"x".repeat(65)] {
            assert_eq!(policy_label(refused), None, "{refused:?}");
        }
    }
}
