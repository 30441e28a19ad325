//! Collection: running a policy in the simulator and recording what happened.
//!
//! [`rollout`] steps a [`Simulator`] with a [`Policy`] and records one [`TrajectoryStep`] per
//! control step; [`Trajectory::digest`] hashes every recorded number bit for bit, so determinism
//! can be checked across runs and thread counts. [`demo_plan`] is a generic pick, lift and
//! release motion for tests and benchmarks (the task experts live in `scripted_policies/`).
//!
//! [`record`] turns an expert run into a verified, rendered episode; [`run`] is a whole
//! collection (slots, shards, threads) of the options and slots in [`slot`]; [`report`] its
//! `collect_report.json`.

pub mod record;
pub mod replay;
pub mod report;
pub mod run;
pub mod slot;

use crate::policy::{Policy, Waypoint, WaypointPolicy};
use crate::sim::{JawCommand, NativeCommand, Observation, Simulator, StepReport};
use std::f64::consts::FRAC_PI_2;

/// One recorded control step: the observation before it, the command, and what it did.
#[derive(Clone, Debug, PartialEq)]
pub struct TrajectoryStep {
    pub observation: Observation,
    pub command: NativeCommand,
    pub report: StepReport,
}

/// A recorded rollout and the final observation.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    pub steps: Vec<TrajectoryStep>,
    pub final_observation: Observation,
}

/// FNV-1a over 64-bit words.
#[derive(Clone, Copy, Debug)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Fnv64(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv64 {
    pub fn write_u64(&mut self, value: u64) {
        for byte in value.to_le_bytes() {
            self.0 ^= u64::from(byte);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    pub fn write_f64(&mut self, value: f64) {
        self.write_u64(value.to_bits());
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

fn hash_observation(hasher: &mut Fnv64, observation: &Observation) {
    hasher.write_u64(observation.step_index);
    observation
        .state7()
        .iter()
        .for_each(|v| hasher.write_f64(*v));
    observation
        .joint_positions
        .iter()
        .for_each(|v| hasher.write_f64(*v));
    hasher.write_u64(observation.bound_object.map_or(u64::MAX, |i| i as u64));
    for object in &observation.objects {
        let pose = object.world_from_object;
        pose.translation
            .vector
            .iter()
            .for_each(|v| hasher.write_f64(*v));
        pose.rotation
            .coords
            .iter()
            .for_each(|v| hasher.write_f64(*v));
        hasher.write_u64(u64::from(object.on_tray) | u64::from(object.on_block) << 1);
    }
}

impl Trajectory {
    /// A hash of every observation and command, bit for bit.
    pub fn digest(&self) -> u64 {
        let mut hasher = Fnv64::default();
        for step in &self.steps {
            hash_observation(&mut hasher, &step.observation);
            step.command
                .to_array()
                .iter()
                .for_each(|v| hasher.write_f64(*v));
        }
        hash_observation(&mut hasher, &self.final_observation);
        hasher.finish()
    }
}

/// Runs `policy` for at most `max_steps` control steps (stopping early when it is done).
pub fn rollout(sim: &mut Simulator, policy: &mut dyn Policy, max_steps: u32) -> Trajectory {
    let mut steps = Vec::with_capacity(max_steps as usize);
    let mut observation = sim.observation();
    for _ in 0..max_steps {
        if policy.is_done() {
            break;
        }
        let command = policy.act(&observation);
        let report = sim.step_native(&command);
        let next = sim.observation();
        steps.push(TrajectoryStep {
            observation,
            command,
            report,
        });
        observation = next;
    }
    Trajectory {
        steps,
        final_observation: observation,
    }
}

/// The demo motion for a scene: hover 5 mm above the first object with the jaws open, descend
/// to its grasp point, close, lift 30 mm, open to release, and wait for it to settle. Scenes
/// without a movable object get a hover over the workspace centre.
pub fn demo_plan(sim: &Simulator) -> WaypointPolicy {
    let observation = sim.observation();
    let Some(object) = observation.objects.first() else {
        let hover = |z: f64, jaw| Waypoint {
            position_m: [0.55, 0.0, z],
            yaw_rad: FRAC_PI_2,
            jaw,
            hold_steps: 0,
            speed_scale: 1.0,
        };
        return WaypointPolicy::new(
            vec![
                hover(0.72, JawCommand::Open),
                hover(0.70, JawCommand::Close),
                hover(0.72, JawCommand::Open),
            ],
            0.6,
        );
    };
    let grasp = object.world_from_object;
    let [x, y, z] = [
        grasp.translation.x,
        grasp.translation.y,
        grasp.translation.z,
    ];
    // The jaws close along the tip's local x: across a needle's wire the yaw is the tangent's
    // angle minus 90 deg; a gauze or block is taken along its short side.
    let object_yaw = crate::sim::psm::euler_xyz(&grasp.rotation)[2];
    let yaw = crate::sim::psm::wrap_angle(object_yaw + FRAC_PI_2);
    let yaw = if yaw.abs() > FRAC_PI_2 {
        crate::sim::psm::wrap_angle(yaw + std::f64::consts::PI)
    } else {
        yaw
    };
    let at = |dz: f64, jaw, hold_steps| Waypoint {
        position_m: [x, y, z + dz],
        yaw_rad: yaw,
        jaw,
        hold_steps,
        speed_scale: 1.0,
    };
    WaypointPolicy::new(
        vec![
            at(0.005, JawCommand::Open, 0),
            at(0.0, JawCommand::Open, 0),
            at(0.0, JawCommand::Close, 0),
            at(0.030, JawCommand::Close, 1),
            at(0.030, JawCommand::Open, 5),
        ],
        0.6,
    )
}
