//! The headless laparoscopic simulator: dVRK PSM kinematics ([`psm`]), control inputs
//! ([`control`]), the rapier world ([`physics`]), the grasp
//! binding rule ([`grasp`]), a trial's memory ([`history`]) and the [`Simulator`] that ties them together.
//!
//! Units are SI (metres, radians, seconds, kilograms); poses are `world_from_*` nalgebra
//! isometries in f64. Only [`physics`] touches rapier types.

pub mod control;
pub mod grasp;
pub mod history;
pub mod observation;
pub mod physics;
pub mod psm;
mod simulator;

pub use crate::scene::{ObjectKind, ObjectSpec, OrganKind, OrganSpec, SceneSpec};
pub use control::{JawCommand, NativeCommand, PhysicalAction, Timing, Workspace};
pub use grasp::GraspRule;
pub use observation::{ObjectState, Observation};
pub use psm::Psm;
pub use simulator::{
    HELD_PENETRATION_M, JAWS_CLOSED_RAD, MOVED_THRESHOLD_M, SimConfig, Simulator, StepReport,
};
