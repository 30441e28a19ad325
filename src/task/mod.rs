//! The eight SurgVLA-Bench tasks: identifiers, names, levels, step limits, instructions (the
//! canonical one and paraphrases), seeded scenes ([`spawn`]) and success predicates
//! ([`success`]).
//!
//! A [`TaskInstance`] is one episode's setup: the scene, the instruction, and which object or
//! mark the instruction names. It is a pure function of (task, seed, [`TaskConfig`]).

mod id;
pub mod instance;
mod placement;
pub mod spawn;
pub mod success;

pub use id::{TaskId, UnknownTask, Z0_M};
pub use spawn::{InstructionChoice, SpawnError, SpawnRanges, TaskConfig, TaskInstance};
pub use success::Verdict;
