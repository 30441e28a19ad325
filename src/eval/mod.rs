//! Closed-loop evaluation: a policy drives an [`Env`](crate::env::Env) of each task for N
//! trials and is scored by the task's success predicate, as the reference benchmark scores VLA
//! models (50 trials per task, step limits 100 / 150, binary success).
//!
//! - [`agents`]: the policies (a remote one behind openpi's protocol, the expert, replay of the
//!   nearest training episode, random, no-op).
//! - [`numpy`] and [`remote`]: openpi's msgpack-numpy encoding and the WebSocket client.
//! - [`run`]: trials (seeds disjoint from collection's, [`trial_seed`]), in parallel for the
//!   built-in policies, and recordings of a few failed trials (MCAP).
//! - [`vector`]: many environments of one task stepped together, the core of the Python
//!   module's gymnasium environments; [`shaping`]: their optional dense reward.
//! - [`progress`]: each trial's stages, progress, failure class and precision figures, from the
//!   simulator's state.
//! - [`perturb`]: perturbation suites (versioned files in `suites/`), their variants drawn per
//!   trial and applied at reset.
//! - [`results`]: success rates with Wilson 95 % intervals, written as JSON, CSV and Markdown.

pub mod agents;
pub mod chart;
mod journal;
pub mod numpy;
mod options;
pub mod perturb;
pub mod progress;
pub mod remote;
pub mod results;
pub mod run;
pub mod shaping;
pub mod vector;

pub use agents::SendExtras;
pub use options::{EvalError, EvalOptions, PolicyChoice, evaluation_spawn_scale, policy_label};
pub use results::{EvalReport, TaskResult, wilson_interval};
pub use run::{evaluate, trial_seed};
