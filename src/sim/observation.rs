//! What the simulator reports after each control step.
//!
//! `state7` is the dataset's `observation.state`: tip x, y, z (m, world), roll, pitch, yaw (rad,
//! Euler xyz with `R = Rz(yaw) Ry(pitch) Rx(roll)`), jaw angle (rad).

use crate::scene::ObjectKind;
use crate::sim::control::JawCommand;
use crate::sim::history::TrialHistory;
use crate::sim::psm::{IkReport, Joints};
use nalgebra::Isometry3;

/// One movable object's state.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectState {
    pub name: String,
    pub kind: ObjectKind,
    /// Pose of the object's grasp frame.
    pub world_from_object: Isometry3<f64>,
    /// Held by the jaws.
    pub bound: bool,
    /// Held by the jaws at any time since the episode began.
    pub ever_bound: bool,
    /// The grasp frame's pose when the jaws last let the object go (None: never released, or
    /// held now).
    pub released_at: Option<Isometry3<f64>>,
    /// In contact with the tray pad.
    pub on_tray: bool,
    /// In contact with the block (never true for the block itself).
    pub on_block: bool,
    /// Distance from the spawn position, metres.
    pub displacement_m: f64,
    /// Moved more than [`crate::sim::simulator::MOVED_THRESHOLD_M`] from its spawn position.
    pub moved: bool,
    /// Asleep in the physics engine (settled).
    pub at_rest: bool,
    /// Linear speed, metres per second.
    pub speed_m_per_s: f64,
}

/// The simulator's observation after a control step.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    pub step_index: u64,
    pub time_secs: f64,
    pub tip_position_m: [f64; 3],
    pub tip_euler_xyz_rad: [f64; 3],
    pub jaw_angle_rad: f64,
    pub jaw_command: JawCommand,
    pub joint_positions: Joints,
    pub objects: Vec<ObjectState>,
    pub bound_object: Option<usize>,
    /// What IK had to clamp on the last step.
    pub ik: IkReport,
    /// What happened since the start that a verdict needs: penetration, the vessel's entries
    /// and closures, releases.
    pub history: TrialHistory,
    /// On the last step the held object met static geometry and the tip stopped above its
    /// target.
    pub descent_stopped: bool,
}

impl Observation {
    /// The 7-D dataset state.
    pub fn state7(&self) -> [f64; 7] {
        let [x, y, z] = self.tip_position_m;
        let [roll, pitch, yaw] = self.tip_euler_xyz_rad;
        [x, y, z, roll, pitch, yaw, self.jaw_angle_rad]
    }

    /// The object with this name.
    pub fn object(&self, name: &str) -> Option<&ObjectState> {
        self.objects.iter().find(|o| o.name == name)
    }
}
