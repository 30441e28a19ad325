//! The eight SurgVLA-Bench tasks: identifiers, names, levels, step limits, instructions (the
//! canonical one and paraphrases), seeded scenes ([`spawn`]) and success predicates
//! ([`success`], with T2-3's clip and T3's placements judged from the trial's history in
//! `clip_rule` and `place_rule`).
//!
//! A [`TaskInstance`] is one episode's setup: the scene, the instruction, and which object or
//! mark the instruction names. It is a pure function of (task, seed, [`TaskConfig`]).

pub mod clip_rule;
mod id;
pub mod instance;
pub mod place_rule;
mod placement;
pub mod prompts;
pub mod spawn;
pub mod success;

pub use id::{TaskId, UnknownTask, UnknownTasks, Z0_M, parse_task_list};
pub use spawn::{InstructionChoice, SpawnError, SpawnRanges, TaskConfig, TaskInstance};
pub use success::Verdict;
