//! Kinematics of the dVRK patient-side manipulator (PSM).
//!
//! The chain is the dVRK's modified Denavit-Hartenberg table (Craig convention:
//! `T_i = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)`) with joint types
//! R, R, P, R, R, R: outer yaw, outer pitch, insertion, instrument roll, wrist pitch, wrist yaw.
//! The kinematic base frame sits at the remote centre of motion (RCM): the first two joints only
//! tilt the shaft about that point, so the shaft passes through the RCM in every pose.
//!
//! Frames and names:
//! - `rcm_from_*`: poses in the kinematic base frame at the RCM; `world_from_*`: world frame.
//! - The *DH tip* frame follows the dVRK tool-tip offset: its z axis is the jaw approach axis.
//! - The *reported tip* frame is the DH tip rotated by a constant so that the reference start
//!   pose (pointing down) reads Euler xyz (-90 deg, 0, 90 deg), as in the reference dataset. In it
//!   the local y axis is the approach axis and the local x axis is the jaws' closing axis.
//!
//! [`Psm::inverse`] is closed-form: the tip pose fixes the wrist-yaw joint, the wrist-pitch joint
//! must lie on the line through the RCM, which fixes the shaft, and the three instrument joints
//! follow from the remaining rotation. Targets out of reach or past a joint limit are clamped and
//! reported in [`IkReport`]; nothing returns NaN.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::{FRAC_PI_2, PI};

/// Number of arm joints (the jaw is separate).
pub const NUM_JOINTS: usize = 6;

/// Modified DH `a_{i-1}` per joint, metres.
const DH_A_M: [f64; NUM_JOINTS] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0091];
/// Modified DH `alpha_{i-1}` per joint, radians.
const DH_ALPHA_RAD: [f64; NUM_JOINTS] = [
    FRAC_PI_2, -FRAC_PI_2, FRAC_PI_2, 0.0, -FRAC_PI_2, -FRAC_PI_2,
];
/// Modified DH `d_i` per joint (the insertion joint adds its value to it), metres.
const DH_D_M: [f64; NUM_JOINTS] = [0.0, 0.0, -0.4318, 0.4162, 0.0, 0.0];
/// Modified DH `theta` offset per joint, radians.
const DH_THETA_OFFSET_RAD: [f64; NUM_JOINTS] =
    [FRAC_PI_2, -FRAC_PI_2, 0.0, 0.0, -FRAC_PI_2, -FRAC_PI_2];
/// Distance from the wrist-yaw (pinch) joint to the tool tip along the approach axis, metres.
pub const TIP_OFFSET_M: f64 = 0.0102;
/// Distance between the wrist-pitch and wrist-yaw axes, metres.
pub const PITCH_TO_YAW_M: f64 = 0.0091;
/// Shaft length from the RCM to the wrist at zero insertion is `DH_D_M[2] + DH_D_M[3]`.
const RCM_TO_WRIST_AT_ZERO_INSERTION_M: f64 = -0.4318 + 0.4162;

/// Jaw opening angle when open, radians (40 deg).
pub const JAW_OPEN_RAD: f64 = 0.698_131_700_797_731_8;
/// Jaw opening angle when closed, radians.
pub const JAW_CLOSED_RAD: f64 = 0.0;

/// The opening angle at which the jaws' tips (each jaw at +-angle/2, [`TIP_OFFSET_M`] long) are
/// `gap_m` apart: where closing jaws stop on a held object.
pub fn jaw_angle_for_gap(gap_m: f64) -> f64 {
    2.0 * (gap_m / (2.0 * TIP_OFFSET_M)).clamp(0.0, 1.0).asin()
}

/// Lower and upper limit of one joint (radians, or metres for the insertion joint).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimit {
    pub min: f64,
    pub max: f64,
}

/// The dVRK PSM joint limits: yaw +-91 deg, pitch +-53 deg, insertion 0..0.24 m, roll +-260 deg,
/// wrist pitch and wrist yaw +-80 deg.
pub const JOINT_LIMITS: [JointLimit; NUM_JOINTS] = [
    JointLimit {
        min: -91.0 * PI / 180.0,
        max: 91.0 * PI / 180.0,
    },
    JointLimit {
        min: -53.0 * PI / 180.0,
        max: 53.0 * PI / 180.0,
    },
    JointLimit {
        min: 0.0,
        max: 0.24,
    },
    JointLimit {
        min: -260.0 * PI / 180.0,
        max: 260.0 * PI / 180.0,
    },
    JointLimit {
        min: -80.0 * PI / 180.0,
        max: 80.0 * PI / 180.0,
    },
    JointLimit {
        min: -80.0 * PI / 180.0,
        max: 80.0 * PI / 180.0,
    },
];

/// Joint positions q1..q6 (rad, rad, m, rad, rad, rad).
pub type Joints = [f64; NUM_JOINTS];

/// What inverse kinematics had to give up to stay reachable and within limits.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IkReport {
    /// Bit `i` set when joint `i` was clamped to its limit.
    pub clamped_joints: u8,
    /// Distance between the requested and the reached tip position, metres.
    pub position_error_m: f64,
    /// Angle between the requested and the reached tip orientation, radians.
    pub orientation_error_rad: f64,
}

impl IkReport {
    /// True when the target was reached exactly (no joint clamped).
    pub fn is_exact(&self) -> bool {
        self.clamped_joints == 0
    }
}

/// All intermediate frames of one forward-kinematics evaluation, in the RCM frame.
#[derive(Clone, Copy, Debug)]
pub struct ChainFrames {
    /// `rcm_from_link[i]` is the pose of DH frame `i + 1`.
    pub rcm_from_link: [Isometry3<f64>; NUM_JOINTS],
    /// Pose of the DH tip frame (z = approach axis).
    pub rcm_from_dh_tip: Isometry3<f64>,
}

/// The PSM: where its RCM is in the world, and its kinematics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Psm {
    /// Pose of the kinematic base frame (at the RCM) in the world.
    pub world_from_rcm: Isometry3<f64>,
}

/// Constant rotation from the DH tip frame to the reported tip frame.
fn dh_tip_from_reported_tip() -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), PI)
        * Rotation3::from_axis_angle(&Vector3::z_axis(), FRAC_PI_2)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), -FRAC_PI_2)
}

/// The dVRK tool-tip offset: the DH tip frame in the wrist-yaw (frame 6) frame.
fn link6_from_dh_tip() -> Isometry3<f64> {
    let rotation = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0);
    Isometry3::from_parts(
        Translation3::new(0.0, TIP_OFFSET_M, 0.0),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation)),
    )
}

/// Each DH row's constant part, `Rx(alpha) * Tx(a)`, computed once (the same operations as
/// per call, so the same bits).
static DH_FIXED: std::sync::LazyLock<[Isometry3<f64>; NUM_JOINTS]> =
    std::sync::LazyLock::new(|| {
        std::array::from_fn(|joint| {
            let rot_x = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), DH_ALPHA_RAD[joint]);
            Isometry3::from_parts(Translation3::identity(), rot_x)
                * Isometry3::from_parts(
                    Translation3::new(DH_A_M[joint], 0.0, 0.0),
                    UnitQuaternion::identity(),
                )
        })
    });

/// [`link6_from_dh_tip`] and the reported tip in the DH tip frame as a quaternion, computed
/// once (a rotation matrix's quaternion is found iteratively).
static TIP_FRAMES: std::sync::LazyLock<(Isometry3<f64>, UnitQuaternion<f64>)> =
    std::sync::LazyLock::new(|| {
        (
            link6_from_dh_tip(),
            UnitQuaternion::from_rotation_matrix(&dh_tip_from_reported_tip()),
        )
    });

/// One row of the modified DH table as a transform.
fn dh_transform(joint: usize, q: f64) -> Isometry3<f64> {
    let (theta, d) = if joint == 2 {
        (DH_THETA_OFFSET_RAD[joint], DH_D_M[joint] + q)
    } else {
        (q + DH_THETA_OFFSET_RAD[joint], DH_D_M[joint])
    };
    let rot_z = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta);
    DH_FIXED[joint]
        * Isometry3::from_parts(Translation3::identity(), rot_z)
        * Isometry3::from_parts(Translation3::new(0.0, 0.0, d), UnitQuaternion::identity())
}

/// Clamps `joints` into [`JOINT_LIMITS`]; returns the bit set of clamped joints.
pub fn clamp_to_limits(joints: &mut Joints) -> u8 {
    let mut clamped = 0u8;
    for (i, (q, limit)) in joints.iter_mut().zip(JOINT_LIMITS.iter()).enumerate() {
        let value = if q.is_finite() { *q } else { 0.0 };
        let bounded = value.clamp(limit.min, limit.max);
        if bounded != *q {
            clamped |= 1 << i;
        }
        *q = bounded;
    }
    clamped
}

/// The rotation of a reported tip frame pointing straight down with the given yaw (the third
/// Euler xyz angle): `Rz(yaw) * Rx(-pi/2)`.
pub fn pointing_down(yaw_rad: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(-FRAC_PI_2, 0.0, yaw_rad)
}

/// Euler xyz angles (roll, pitch, yaw) with `R = Rz(yaw) Ry(pitch) Rx(roll)`, radians.
pub fn euler_xyz(rotation: &UnitQuaternion<f64>) -> [f64; 3] {
    let (roll, pitch, yaw) = rotation.euler_angles();
    [roll, pitch, yaw]
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let wrapped = (angle_rad + PI).rem_euclid(2.0 * PI) - PI;
    if wrapped <= -PI {
        wrapped + 2.0 * PI
    } else {
        wrapped
    }
}

impl Psm {
    /// The reference mounting: arm base at (0.05, 0.24, 0.8524) m rotated -110 deg about z, and
    /// the RCM 0.4864 m from the base along the base's y axis, at the base's height.
    ///
    /// **Ours:** the reference gives the base pose and the base-to-RCM distance; putting the RCM
    /// along the base y axis places it above the workspace (about 0.16 m from its centre), the
    /// only placement from which the 0.24 m insertion range reaches the whole workspace.
    pub fn reference() -> Self {
        let base = Isometry3::from_parts(
            Translation3::new(0.05, 0.24, 0.8524),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -110f64.to_radians()),
        );
        let base_to_rcm = Isometry3::translation(0.0, 0.4864, 0.0);
        let world_from_rcm = base * base_to_rcm;
        Psm {
            world_from_rcm: Isometry3::from_parts(world_from_rcm.translation, base.rotation),
        }
    }

    /// RCM position in the world, metres.
    pub fn rcm_world(&self) -> Point3<f64> {
        self.world_from_rcm * Point3::origin()
    }

    /// Forward kinematics: every DH frame and the DH tip, in the RCM frame.
    pub fn chain(&self, joints: &Joints) -> ChainFrames {
        let mut pose = Isometry3::identity();
        let mut rcm_from_link = [Isometry3::identity(); NUM_JOINTS];
        for (i, q) in joints.iter().enumerate() {
            pose *= dh_transform(i, *q);
            rcm_from_link[i] = pose;
        }
        ChainFrames {
            rcm_from_link,
            rcm_from_dh_tip: pose * TIP_FRAMES.0,
        }
    }

    /// Forward kinematics: the reported tip pose in the world.
    pub fn forward(&self, joints: &Joints) -> Isometry3<f64> {
        let frames = self.chain(joints);
        self.world_from_rcm
            * frames.rcm_from_dh_tip
            * Isometry3::from_parts(Translation3::identity(), TIP_FRAMES.1)
    }

    /// Closed-form inverse kinematics for a reported tip pose in the world.
    ///
    /// `roll_hint_rad` picks among the instrument-roll solutions that differ by full turns: the
    /// one nearest the hint within limits (pass the current roll for continuous motion).
    /// Unreachable or out-of-limit targets are clamped; the report says by how much.
    pub fn inverse(
        &self,
        world_from_tip: &Isometry3<f64>,
        roll_hint_rad: f64,
    ) -> (Joints, IkReport) {
        let finite = world_from_tip
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
            && world_from_tip.rotation.coords.iter().all(|v| v.is_finite());
        if !finite {
            // Nothing sensible to reach: the home pose, every joint reported as clamped.
            let home = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0];
            let report = IkReport {
                clamped_joints: (1 << NUM_JOINTS) - 1,
                position_error_m: f64::INFINITY,
                orientation_error_rad: PI,
            };
            return (home, report);
        }
        let reported_tip_from_dh_tip =
            UnitQuaternion::from_rotation_matrix(&dh_tip_from_reported_tip().inverse());
        let rcm_from_dh_tip = self.world_from_rcm.inverse()
            * world_from_tip
            * Isometry3::from_parts(Translation3::identity(), reported_tip_from_dh_tip);
        let mut joints = solve_unclamped(&rcm_from_dh_tip, roll_hint_rad);
        let clamped_joints = clamp_to_limits(&mut joints);
        let reached = self.forward(&joints);
        let report = IkReport {
            clamped_joints,
            position_error_m: (reached.translation.vector - world_from_tip.translation.vector)
                .norm(),
            orientation_error_rad: reached.rotation.angle_to(&world_from_tip.rotation),
        };
        (joints, report)
    }
}

/// The closed-form solution before clamping. Every branch yields finite numbers.
fn solve_unclamped(rcm_from_dh_tip: &Isometry3<f64>, roll_hint_rad: f64) -> Joints {
    let tip_rotation = rcm_from_dh_tip.rotation.to_rotation_matrix();
    let approach = tip_rotation * Vector3::z();
    // The dVRK tool-tip offset: tip x = -z6, tip y = -x6, tip z = y6.
    let z6 = -(tip_rotation * Vector3::x());
    let x6 = -(tip_rotation * Vector3::y());
    let pinch = rcm_from_dh_tip.translation.vector - TIP_OFFSET_M * approach;

    // The wrist-pitch joint lies PITCH_TO_YAW_M from the pinch joint, perpendicular to z6, on the
    // side of the RCM (the RCM is at the origin of this frame).
    let to_rcm = -pinch;
    let in_plane = to_rcm - z6 * z6.dot(&to_rcm);
    let toward_palm = in_plane.try_normalize(1e-12).unwrap_or_else(|| {
        -approach
            .cross(&z6)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::x)
    });
    let palm = pinch + PITCH_TO_YAW_M * toward_palm;
    let insertion_from_rcm_m = palm.norm();
    let shaft = palm.try_normalize(1e-12).unwrap_or_else(|| -Vector3::z());

    let q1 = shaft.x.atan2(-shaft.z);
    let q2 = -shaft
        .y
        .atan2((shaft.x * shaft.x + shaft.z * shaft.z).sqrt());
    let q3 = insertion_from_rcm_m - RCM_TO_WRIST_AT_ZERO_INSERTION_M;

    // Frame 3 orientation from the first three joints (the insertion does not rotate).
    let frame3 = dh_transform(0, q1) * dh_transform(1, q2) * dh_transform(2, q3);
    let r3 = frame3.rotation.to_rotation_matrix();
    let x5 = -toward_palm;
    let z5 = x5.cross(&z6);
    // z5 = y4 = R3 * (-sin q4, cos q4, 0).
    let z5_in_3 = r3.transpose() * z5;
    let q4_principal = (-z5_in_3.x).atan2(z5_in_3.y);
    let q4 = nearest_turn(q4_principal, roll_hint_rad, JOINT_LIMITS[3]);
    let frame4 = frame3 * dh_transform(3, q4);
    let r4 = frame4.rotation.to_rotation_matrix();
    // x5 in frame 4 = (sin q5, 0, cos q5).
    let q5 = x5
        .dot(&(r4 * Vector3::x()))
        .atan2(x5.dot(&(r4 * Vector3::z())));
    // x6 in frame 5 = (sin q6, 0, cos q6).
    let x5_axis = x5;
    let q6 = x6.dot(&x5_axis).atan2(x6.dot(&z5));
    [q1, q2, q3, q4, q5, q6]
}

/// The angle `principal + 2 pi k` nearest `hint` that lies within `limit`, if any; otherwise the
/// candidate nearest the hint.
fn nearest_turn(principal: f64, hint: f64, limit: JointLimit) -> f64 {
    if !principal.is_finite() {
        return 0.0;
    }
    let hint = if hint.is_finite() { hint } else { 0.0 };
    let turn = 2.0 * PI;
    let k_min = ((limit.min - principal) / turn).ceil();
    let k_max = ((limit.max - principal) / turn).floor();
    if k_min > k_max {
        // No full-turn copy lies within the limits: the copy nearest the limit range.
        let k = ((limit.min.max(hint.min(limit.max)) - principal) / turn).round();
        return principal + turn * k;
    }
    let k = ((hint - principal) / turn).round().clamp(k_min, k_max);
    principal + turn * k
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointing_down_reads_reference_euler_angles() {
        let euler = euler_xyz(&pointing_down(FRAC_PI_2));
        assert!((euler[0] + FRAC_PI_2).abs() < 1e-12);
        assert!(euler[1].abs() < 1e-12);
        assert!((euler[2] - FRAC_PI_2).abs() < 1e-12);
        // Local y is the approach axis and points down.
        let approach = pointing_down(0.3) * Vector3::y();
        assert!((approach - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    }

    #[test]
    fn zero_wrist_tip_continues_along_shaft() {
        let psm = Psm {
            world_from_rcm: Isometry3::identity(),
        };
        let frames = psm.chain(&[0.2, -0.3, 0.15, 0.4, 0.0, 0.0]);
        let wrist = frames.rcm_from_link[4].translation.vector;
        let tip = frames.rcm_from_dh_tip.translation.vector;
        let shaft = wrist.normalize();
        assert!((tip - wrist).normalize().dot(&shaft) > 1.0 - 1e-12);
        assert!(((tip - wrist).norm() - (PITCH_TO_YAW_M + TIP_OFFSET_M)).abs() < 1e-12);
        assert!((wrist.norm() - (0.15 + RCM_TO_WRIST_AT_ZERO_INSERTION_M)).abs() < 1e-12);
    }

    #[test]
    fn wrap_angle_stays_in_range() {
        for k in -20..=20 {
            let a = wrap_angle(f64::from(k) * 0.7);
            assert!(a > -PI && a <= PI);
        }
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
    }

    #[test]
    fn nearest_turn_prefers_within_limits() {
        let limit = JOINT_LIMITS[3];
        let q = nearest_turn(2.0, 2.0 - 2.0 * PI + 0.1, limit);
        assert!((q - (2.0 - 2.0 * PI)).abs() < 1e-12);
        let q = nearest_turn(2.0, 1.0, limit);
        assert!((q - 2.0).abs() < 1e-12);
        let q = nearest_turn(0.5, 100.0, limit);
        assert!(q <= limit.max);
    }
}
