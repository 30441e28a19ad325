//! Control inputs: the native normalised command, the physical 7-D dataset action, the workspace
//! box commands are clipped to, and the control/physics timing.
//!
//! The native command `[dx, dy, dz, dyaw, jaw]` is in [-1, 1]: position moves by `a * 0.01 m`
//! in the world frame, yaw by `a * 30 deg`, and `jaw < 0` closes the jaws (otherwise they open).
//! The physical action `[dx, dy, dz (m), droll, dpitch, dyaw (rad), gripper]` is what a dataset
//! records; `gripper >= 0.5` means open. Both become a [`TipTarget`] clipped to the workspace.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Metres of tip motion per unit of native command.
pub const NATIVE_POSITION_SCALE_M: f64 = 0.01;
/// Radians of yaw per unit of native command (30 deg).
pub const NATIVE_YAW_SCALE_RAD: f64 = std::f64::consts::PI / 6.0;
/// Largest rotation delta accepted per control step from a physical action, radians.
pub const MAX_ROTATION_STEP_RAD: f64 = std::f64::consts::PI / 6.0;

/// Control and physics rates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// Control steps per second (5 Hz in the reference).
    pub control_hz: u32,
    /// Physics substeps per control step (48 gives 240 Hz physics at 5 Hz control).
    pub substeps: u32,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            control_hz: 5,
            substeps: 48,
        }
    }
}

impl Timing {
    /// Duration of one control step, seconds.
    pub fn control_dt_secs(&self) -> f64 {
        1.0 / f64::from(self.control_hz.max(1))
    }

    /// Duration of one physics substep, seconds.
    pub fn physics_dt_secs(&self) -> f64 {
        self.control_dt_secs() / f64::from(self.substeps.max(1))
    }
}

/// The box the tool tip may occupy, world frame, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workspace {
    pub min_m: [f64; 3],
    pub max_m: [f64; 3],
}

impl Workspace {
    /// The reference workspace x 0.50..0.60, y -0.05..0.05, z z0..0.7552, widened as the reference
    /// clips commands: 4 mm in x and y and 16 mm upward.
    ///
    /// **Ours:** the floor is 0.5 mm above the tray pad (z = 0.6785) instead of the reference
    /// z0 = 0.6852. The reference floor keeps the tip 7 mm above the pad, out of the 3 mm binding
    /// range of a 2.6 mm gauze lying on it. The whole reference box (x 0.50..0.60, y +-0.05,
    /// z up to 0.7552) is reachable at any yaw; the top of the widening beyond x = 0.59 tilts the
    /// shaft past the outer pitch limit, where IK clamps and reports.
    pub fn reference() -> Self {
        Workspace {
            min_m: [0.496, -0.054, 0.6785],
            max_m: [0.604, 0.054, 0.7712],
        }
    }

    /// Clamps a position into the box; returns the clamped point and whether it moved.
    pub fn clip(&self, position_m: Vector3<f64>) -> (Vector3<f64>, bool) {
        let mut out = position_m;
        for axis in 0..3 {
            let value = if out[axis].is_finite() {
                out[axis]
            } else {
                self.min_m[axis]
            };
            out[axis] = value.clamp(self.min_m[axis], self.max_m[axis]);
        }
        let clipped = out != position_m;
        (out, clipped)
    }

    /// True when the point lies inside the box (within `tolerance_m`).
    pub fn contains(&self, position_m: &Vector3<f64>, tolerance_m: f64) -> bool {
        (0..3).all(|axis| {
            position_m[axis] >= self.min_m[axis] - tolerance_m
                && position_m[axis] <= self.max_m[axis] + tolerance_m
        })
    }
}

/// Whether the jaws are commanded open or closed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum JawCommand {
    Open,
    Close,
}

/// The native normalised command, each component in [-1, 1] (clipped on use).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NativeCommand {
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    pub dyaw: f64,
    /// `< 0` closes the jaws, otherwise they open.
    pub jaw: f64,
}

impl NativeCommand {
    /// Builds a command from `[dx, dy, dz, dyaw, jaw]`.
    pub fn from_array(values: [f64; 5]) -> Self {
        let [dx, dy, dz, dyaw, jaw] = values;
        NativeCommand {
            dx,
            dy,
            dz,
            dyaw,
            jaw,
        }
    }

    /// The command as `[dx, dy, dz, dyaw, jaw]`.
    pub fn to_array(&self) -> [f64; 5] {
        [self.dx, self.dy, self.dz, self.dyaw, self.jaw]
    }

    /// The jaw command it encodes.
    pub fn jaw_command(&self) -> JawCommand {
        if self.jaw < 0.0 {
            JawCommand::Close
        } else {
            JawCommand::Open
        }
    }
}

/// The physical 7-D action a dataset records.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhysicalAction {
    /// Tip translation in the world frame, metres.
    pub delta_position_m: [f64; 3],
    /// Change of the tip's Euler xyz angles (roll, pitch, yaw), radians.
    pub delta_euler_rad: [f64; 3],
    /// Continuous gripper state: 1 open, 0 closed (`>= 0.5` reads as open).
    pub gripper: f64,
}

/// The reference's action space, per control step: at most this much translation along each
/// world axis, metres (a native command of 1 is 1 cm) ...
pub const MAX_STEP_TRANSLATION_M: f64 = 0.01;
/// ... and at most this much yaw, radians (30 deg); roll and pitch never change (the tool keeps
/// pointing down).
pub const MAX_STEP_YAW_RAD: f64 = std::f64::consts::PI / 6.0;
/// A roll or pitch change below this is float noise, not a command to tilt, radians.
const TILT_NOISE_RAD: f64 = 1e-9;

impl PhysicalAction {
    /// This action within the reference's action space: each translation clipped to
    /// [`MAX_STEP_TRANSLATION_M`], roll and pitch zero, yaw clipped to [`MAX_STEP_YAW_RAD`],
    /// anything not finite no motion. Returns the action and whether it had to be changed
    /// (beyond float noise in roll and pitch).
    pub fn within_reference(&self) -> (PhysicalAction, bool) {
        let mut clipped = false;
        let mut limit = |v: f64, max: f64| {
            let c = if v.is_finite() {
                v.clamp(-max, max)
            } else {
                0.0
            };
            clipped |= c != v;
            c
        };
        let delta_position_m = self
            .delta_position_m
            .map(|v| limit(v, MAX_STEP_TRANSLATION_M));
        let [droll, dpitch, dyaw] = self.delta_euler_rad;
        let dyaw = limit(dyaw, MAX_STEP_YAW_RAD);
        let tilted = [droll, dpitch]
            .iter()
            .any(|v| !v.is_finite() || v.abs() > TILT_NOISE_RAD);
        (
            PhysicalAction {
                delta_position_m,
                delta_euler_rad: [0.0, 0.0, dyaw],
                gripper: self.gripper,
            },
            clipped || tilted,
        )
    }

    /// Builds an action from the dataset layout `[dx, dy, dz, droll, dpitch, dyaw, gripper]`.
    pub fn from_array(values: [f64; 7]) -> Self {
        let [dx, dy, dz, droll, dpitch, dyaw, gripper] = values;
        PhysicalAction {
            delta_position_m: [dx, dy, dz],
            delta_euler_rad: [droll, dpitch, dyaw],
            gripper,
        }
    }

    /// The dataset layout `[dx, dy, dz, droll, dpitch, dyaw, gripper]`.
    pub fn to_array(&self) -> [f64; 7] {
        let [dx, dy, dz] = self.delta_position_m;
        let [droll, dpitch, dyaw] = self.delta_euler_rad;
        [dx, dy, dz, droll, dpitch, dyaw, self.gripper]
    }

    /// The jaw command it encodes.
    pub fn jaw_command(&self) -> JawCommand {
        if self.gripper >= 0.5 {
            JawCommand::Open
        } else {
            JawCommand::Close
        }
    }
}

/// A tip pose to move to within one control step, already clipped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TipTarget {
    pub world_from_tip: Isometry3<f64>,
    pub jaw: JawCommand,
    /// True when the workspace clipped the requested position.
    pub clipped: bool,
}

fn clip_unit(value: f64) -> f64 {
    if value.is_finite() {
        value.clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

fn clip_rotation(value: f64) -> f64 {
    if value.is_finite() {
        value.clamp(-MAX_ROTATION_STEP_RAD, MAX_ROTATION_STEP_RAD)
    } else {
        0.0
    }
}

/// The target of a native command from the current tip pose: pointing down, yaw changed.
pub fn native_target(
    workspace: &Workspace,
    current_position_m: Vector3<f64>,
    current_yaw_rad: f64,
    command: &NativeCommand,
) -> TipTarget {
    let delta = Vector3::new(
        clip_unit(command.dx),
        clip_unit(command.dy),
        clip_unit(command.dz),
    ) * NATIVE_POSITION_SCALE_M;
    let (position, clipped) = workspace.clip(current_position_m + delta);
    let yaw = current_yaw_rad + clip_unit(command.dyaw) * NATIVE_YAW_SCALE_RAD;
    TipTarget {
        world_from_tip: Isometry3::from_parts(
            Translation3::from(position),
            crate::sim::psm::pointing_down(yaw),
        ),
        jaw: command.jaw_command(),
        clipped,
    }
}

/// The target of a physical action from the current tip pose (Euler angles are added).
pub fn physical_target(
    workspace: &Workspace,
    current_position_m: Vector3<f64>,
    current_euler_rad: [f64; 3],
    action: &PhysicalAction,
) -> TipTarget {
    let [dx, dy, dz] = action.delta_position_m;
    let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
    let delta = Vector3::new(finite(dx), finite(dy), finite(dz));
    let (position, clipped) = workspace.clip(current_position_m + delta);
    let [roll, pitch, yaw] = current_euler_rad;
    let [droll, dpitch, dyaw] = action.delta_euler_rad;
    let rotation = UnitQuaternion::from_euler_angles(
        roll + clip_rotation(droll),
        pitch + clip_rotation(dpitch),
        yaw + clip_rotation(dyaw),
    );
    TipTarget {
        world_from_tip: Isometry3::from_parts(Translation3::from(position), rotation),
        jaw: action.jaw_command(),
        clipped,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actions_are_clipped_to_the_references_action_space() {
        let clip = |values: [f64; 7]| {
            let (action, clipped) = PhysicalAction::from_array(values).within_reference();
            (action.to_array(), clipped)
        };
        // Within it: unchanged (float noise in roll and pitch becomes an exact zero).
        let (a, clipped) = clip([0.01, -0.004, 0.0, 1e-15, -1e-15, 0.5, 1.0]);
        assert_eq!(a, [0.01, -0.004, 0.0, 0.0, 0.0, 0.5, 1.0]);
        assert!(!clipped);
        // 5 cm in one step, a tilt, 90 deg of yaw, NaN: 1 cm, no tilt, 30 deg, no motion.
        let (a, clipped) = clip([0.05, -0.02, f64::NAN, 0.3, 0.0, 1.6, 0.0]);
        assert_eq!(a[..3], [0.01, -0.01, 0.0]);
        assert_eq!(a[3..5], [0.0, 0.0]);
        assert!((a[5] - MAX_STEP_YAW_RAD).abs() < 1e-12);
        assert!(clipped);
        assert!(
            clip([0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 1.0]).1,
            "pitch alone is clipped"
        );
    }

    #[test]
    fn timing_defaults_are_5hz_over_240hz() {
        let timing = Timing::default();
        assert!((timing.control_dt_secs() - 0.2).abs() < 1e-12);
        assert!((timing.physics_dt_secs() - 1.0 / 240.0).abs() < 1e-12);
    }

    #[test]
    fn native_command_is_clipped_to_unit_and_workspace() {
        let ws = Workspace::reference();
        let start = Vector3::new(0.60, 0.0, 0.70);
        let target = native_target(
            &ws,
            start,
            0.0,
            &NativeCommand::from_array([5.0, -0.5, f64::NAN, 9.0, -1.0]),
        );
        let p = target.world_from_tip.translation.vector;
        assert!((p.x - 0.604).abs() < 1e-12, "x clipped to the widened box");
        assert!((p.y + 0.005).abs() < 1e-12, "half a unit is 5 mm");
        assert!((p.z - 0.70).abs() < 1e-12, "NaN is no motion");
        assert!(target.clipped);
        assert_eq!(target.jaw, JawCommand::Close);
        let yaw = crate::sim::psm::euler_xyz(&target.world_from_tip.rotation)[2];
        assert!(
            (yaw - NATIVE_YAW_SCALE_RAD).abs() < 1e-9,
            "dyaw clipped to one unit"
        );
    }

    #[test]
    fn physical_action_round_trips_its_array() {
        let values = [0.001, -0.002, 0.003, 0.0, 0.0, 0.1, 1.0];
        assert_eq!(PhysicalAction::from_array(values).to_array(), values);
        assert_eq!(
            PhysicalAction::from_array(values).jaw_command(),
            JawCommand::Open
        );
        assert_eq!(
            PhysicalAction {
                gripper: 0.2,
                ..Default::default()
            }
            .jaw_command(),
            JawCommand::Close
        );
    }
}
