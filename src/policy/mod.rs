//! Policies that drive the simulator with native commands.
//!
//! [`WaypointPolicy`] is the reference expert's controller: toward the current waypoint the
//! command is `(waypoint - tip) / 0.01 m`, scaled down so its largest component is at most 1,
//! times a speed factor; the yaw command is the yaw error in units of 30 deg, clipped to +-0.4.
//! A waypoint is cleared when the tip is within `position_tolerance_m` of it, the yaw error is
//! under `yaw_tolerance_rad`, the jaws have reached their command, and it has been held for
//! `hold_steps` steps. The task experts of `scripted_policies/` ([`plan`], [`library`]) compile
//! to waypoint lists.

pub mod library;
pub mod plan;
mod waypoint;

pub use library::ExpertLibrary;
pub use plan::{ExpertPlan, ExpertPolicy, PlanError};
pub use waypoint::{Policy, RandomPolicy, Sequence, Waypoint, WaypointPolicy};
