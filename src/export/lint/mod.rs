//! The quality lint: whether a dataset is any good to train on. Formats gather each episode's
//! numeric series ([`EpisodeSeries`]) while they check it, and, where frames are decoded, a
//! summary of every camera frame ([`cameras::FrameLook`]); [`lint`] judges them and reports
//! into [`Findings`]: one finding per defect (check, episode, frame), a check that fires on
//! every episode once with the count, and one [`LintSummary`] line per check that ran.
//!
//! The checks, by module: [`motion`] (what lerobot-doctor judges of actions and observations:
//! frozen actions, jumps, clipping, stuck or constant dimensions, outliers, drift, duplicate
//! episodes), [`episodes`] (lengths against policies' action chunks, tasks, instructions,
//! splits), [`surgical`] (state/action lag, quaternions, gripper range, pose jumps, units,
//! epoch timestamps) and [`cameras`] (frozen, blank and swapped cameras). Every threshold is a
//! named constant there, and docs/validate.md lists them.

pub mod cameras;
pub mod episodes;
mod judge;
pub mod motion;
mod series;
pub mod surgical;
#[cfg(test)]
mod testing;

pub use crate::export::findings::LintSummary;
pub use judge::lint;
pub use series::{EpisodeSeries, LintDataset, LintFeature, Series};
