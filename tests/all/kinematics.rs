//! PSM forward/inverse kinematics: round trips, limits, the RCM.

use crate::util::tip_at;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use surgvla::rng::SplitMix64;
use surgvla::sim::Workspace;
use surgvla::sim::psm::{JOINT_LIMITS, Joints, Psm, clamp_to_limits};

#[test]
fn ik_fk_round_trip_over_the_workspace_grid() {
    let psm = Psm::reference();
    // The reference box x 0.50..0.60, y -0.05..0.05, from our floor to 0.7552: every yaw reaches.
    let widened = Workspace::reference();
    let ws = Workspace {
        min_m: [0.50, -0.05, widened.min_m[2]],
        max_m: [0.60, 0.05, 0.7552],
    };
    let mut worst_m = 0.0f64;
    let mut count = 0;
    for ix in 0..=6 {
        for iy in 0..=6 {
            for iz in 0..=5 {
                for yaw_deg in [-170.0, -90.0, -30.0, 0.0, 45.0, 90.0, 135.0, 180.0] {
                    let lerp = |axis: usize, t: f64| {
                        ws.min_m[axis] + (ws.max_m[axis] - ws.min_m[axis]) * t
                    };
                    let target = tip_at(
                        lerp(0, f64::from(ix) / 6.0),
                        lerp(1, f64::from(iy) / 6.0),
                        lerp(2, f64::from(iz) / 5.0),
                        f64::to_radians(yaw_deg),
                    );
                    let (joints, report) = psm.inverse(&target, 0.0);
                    assert!(
                        report.is_exact(),
                        "clamped {:#b} at {target:?}",
                        report.clamped_joints
                    );
                    let reached = psm.forward(&joints);
                    let error = (reached.translation.vector - target.translation.vector).norm();
                    worst_m = worst_m.max(error);
                    assert!(reached.rotation.angle_to(&target.rotation) < 1e-9);
                    count += 1;
                }
            }
        }
    }
    assert!(
        worst_m < 1e-6,
        "worst position error {worst_m} m over {count} targets"
    );
    // The widened box's top far corner tilts the shaft past the 53 deg pitch limit: reported.
    let (joints, report) = psm.inverse(&tip_at(0.604, 0.054, 0.7712, 0.0), 0.0);
    assert_eq!(report.clamped_joints, 0b10);
    assert_eq!(joints[1], JOINT_LIMITS[1].min);
    assert!(report.position_error_m > 1e-4);
}

#[test]
fn fk_ik_round_trip_for_random_joints_within_limits() {
    let psm = Psm::reference();
    let mut rng = SplitMix64::new(11);
    for _ in 0..2000 {
        let mut joints: Joints = [0.0; 6];
        for (q, limit) in joints.iter_mut().zip(JOINT_LIMITS.iter()) {
            *q = rng.uniform(limit.min, limit.max);
        }
        // Keep the wrist away from the +-90 deg singular configurations and the shaft off the
        // degenerate insertion near the RCM.
        joints[2] = joints[2].max(0.03);
        let tip = psm.forward(&joints);
        let (solved, report) = psm.inverse(&tip, joints[3]);
        assert!(report.is_exact(), "{joints:?} -> {solved:?}");
        for (a, b) in joints.iter().zip(solved.iter()) {
            assert!((a - b).abs() < 1e-7, "{joints:?} -> {solved:?}");
        }
    }
}

#[test]
fn out_of_reach_targets_are_clamped_and_finite() {
    let psm = Psm::reference();
    let far = [
        tip_at(1.5, 0.0, 0.2, 0.0),
        tip_at(0.507, 0.074, 0.853, 0.0),
        tip_at(0.55, 0.0, 0.30, 1.0),
        Isometry3::from_parts(
            Translation3::new(0.55, 0.0, 0.70),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.0),
        ),
        tip_at(f64::NAN, 0.0, f64::INFINITY, f64::NAN),
    ];
    for target in far {
        let (joints, report) = psm.inverse(&target, 0.0);
        assert!(joints.iter().all(|q| q.is_finite()), "{joints:?}");
        for (q, limit) in joints.iter().zip(JOINT_LIMITS.iter()) {
            assert!(*q >= limit.min && *q <= limit.max, "{joints:?}");
        }
        assert!(!report.is_exact(), "{target:?} should need clamping");
        assert!(
            report.position_error_m.is_finite()
                || target.translation.vector.iter().any(|v| !v.is_finite())
        );
    }
}

#[test]
fn clamp_to_limits_reports_each_joint() {
    let mut joints = [2.0, -1.0, 0.3, 0.0, 1.5, -1.5];
    let clamped = clamp_to_limits(&mut joints);
    assert_eq!(clamped, 0b11_0111);
    assert_eq!(joints[2], 0.24);
    assert_eq!(joints[3], 0.0);
}

/// Distance from the RCM to the shaft line through frames 3 and 5 (the wrist), world frame.
fn rcm_to_shaft_m(psm: &Psm, joints: &Joints) -> f64 {
    let frames = psm.chain(joints);
    let a = psm.world_from_rcm * Point3::from(frames.rcm_from_link[2].translation.vector);
    let b = psm.world_from_rcm * Point3::from(frames.rcm_from_link[4].translation.vector);
    let rcm = psm.rcm_world();
    let direction = (b - a).normalize();
    let offset = rcm - a;
    (offset - direction * offset.dot(&direction)).norm()
}

#[test]
fn shaft_passes_through_the_rcm_in_every_pose() {
    let psm = Psm::reference();
    let mut rng = SplitMix64::new(5);
    for _ in 0..5000 {
        let mut joints: Joints = [0.0; 6];
        for (q, limit) in joints.iter_mut().zip(JOINT_LIMITS.iter()) {
            *q = rng.uniform(limit.min, limit.max);
        }
        assert!(rcm_to_shaft_m(&psm, &joints) < 1e-6, "{joints:?}");
    }
}

#[test]
fn rcm_holds_along_a_simulated_trajectory() {
    use surgvla::collect::rollout;
    use surgvla::policy::RandomPolicy;
    let mut sim = crate::util::simulator(crate::util::three_objects(0.0));
    let trajectory = rollout(&mut sim, &mut RandomPolicy::new(3), 60);
    let psm = sim.config().psm;
    for step in &trajectory.steps {
        assert!(rcm_to_shaft_m(&psm, &step.observation.joint_positions) < 1e-6);
    }
}

#[test]
fn start_pose_matches_the_reference() {
    let sim = crate::util::simulator(crate::util::three_objects(0.0));
    let observation = sim.observation();
    let [x, y, z] = observation.tip_position_m;
    assert!((x - 0.50).abs() < 1e-9 && (y - 0.05).abs() < 1e-9 && (z - 0.7202).abs() < 1e-9);
    let euler = observation.tip_euler_xyz_rad;
    assert!((euler[0].to_degrees() + 90.0).abs() < 1e-6);
    assert!(euler[1].abs() < 1e-6);
    assert!((euler[2].to_degrees() - 90.0).abs() < 1e-6);
    assert!((observation.jaw_angle_rad.to_degrees() - 40.0).abs() < 1e-9);
}
