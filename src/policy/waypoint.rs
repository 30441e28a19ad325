//! What a policy is ([`Policy`]: an observation in, an action out) and the simple ones the
//! experts are made of: waypoints reached in turn ([`WaypointPolicy`]), random actions, and one
//! policy after another ([`Sequence`]).

use crate::sim::control::{
    JawCommand, NATIVE_POSITION_SCALE_M, NATIVE_YAW_SCALE_RAD, NativeCommand,
};
use crate::sim::observation::Observation;
use crate::sim::psm::{JAW_CLOSED_RAD, JAW_OPEN_RAD, wrap_angle};

/// Anything that maps an observation to a native command.
pub trait Policy {
    /// The command for this observation.
    fn act(&mut self, observation: &Observation) -> NativeCommand;
    /// True once the policy has nothing left to do.
    fn is_done(&self) -> bool;
}

/// One target of a waypoint plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Waypoint {
    pub position_m: [f64; 3],
    /// Tip yaw (third Euler xyz angle), radians.
    pub yaw_rad: f64,
    pub jaw: JawCommand,
    /// Extra steps to stay once reached (e.g. to let a released object settle).
    pub hold_steps: u32,
    /// Multiplies the policy's speed factor toward this waypoint (1 = unchanged; below 1 for
    /// fine motions).
    pub speed_scale: f64,
}

/// Follows a list of waypoints with the reference expert's proportional controller.
#[derive(Clone, Debug)]
pub struct WaypointPolicy {
    waypoints: Vec<Waypoint>,
    current: usize,
    held: u32,
    pub speed_factor: f64,
    pub position_tolerance_m: f64,
    pub yaw_tolerance_rad: f64,
}

impl WaypointPolicy {
    /// A policy over `waypoints` with the reference tolerances (1 mm, 0.1 rad).
    pub fn new(waypoints: Vec<Waypoint>, speed_factor: f64) -> Self {
        WaypointPolicy {
            waypoints,
            current: 0,
            held: 0,
            speed_factor,
            position_tolerance_m: 0.001,
            yaw_tolerance_rad: 0.1,
        }
    }

    /// Index of the waypoint being approached.
    pub fn current_index(&self) -> usize {
        self.current
    }

    fn reached(&self, waypoint: &Waypoint, observation: &Observation) -> bool {
        let mut error = position_error(waypoint, observation);
        // A held object resting on a surface stops the descent: a waypoint below counts as
        // reached in height.
        if observation.descent_stopped && error[2] < 0.0 {
            error[2] = 0.0;
        }
        let distance = error.iter().map(|e| e * e).sum::<f64>().sqrt();
        let yaw_error = wrap_angle(waypoint.yaw_rad - observation.tip_euler_xyz_rad[2]).abs();
        // Closing jaws stop on a held object.
        let jaws_there = match waypoint.jaw {
            JawCommand::Open => (observation.jaw_angle_rad - JAW_OPEN_RAD).abs() < 1e-6,
            JawCommand::Close => {
                observation.bound_object.is_some()
                    || (observation.jaw_angle_rad - JAW_CLOSED_RAD).abs() < 1e-6
            }
        };
        distance <= self.position_tolerance_m
            && yaw_error <= self.yaw_tolerance_rad
            && observation.jaw_command == waypoint.jaw
            && jaws_there
    }
}

fn position_error(waypoint: &Waypoint, observation: &Observation) -> [f64; 3] {
    let mut error = [0.0; 3];
    for (axis, e) in error.iter_mut().enumerate() {
        *e = waypoint.position_m[axis] - observation.tip_position_m[axis];
    }
    error
}

impl Policy for WaypointPolicy {
    fn act(&mut self, observation: &Observation) -> NativeCommand {
        while let Some(waypoint) = self.waypoints.get(self.current).copied() {
            if !self.reached(&waypoint, observation) {
                break;
            }
            if self.held < waypoint.hold_steps {
                self.held += 1;
                break;
            }
            self.current += 1;
            self.held = 0;
        }
        let Some(waypoint) = self
            .waypoints
            .get(self.current)
            .or(self.waypoints.last())
            .copied()
        else {
            return NativeCommand::default();
        };
        let error = position_error(&waypoint, observation);
        let mut delta = error.map(|e| e / NATIVE_POSITION_SCALE_M);
        let largest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        if largest > 1.0 {
            delta = delta.map(|d| d / largest);
        }
        let yaw_error = wrap_angle(waypoint.yaw_rad - observation.tip_euler_xyz_rad[2]);
        let speed = self.speed_factor * waypoint.speed_scale;
        NativeCommand {
            dx: delta[0] * speed,
            dy: delta[1] * speed,
            dz: delta[2] * speed,
            dyaw: (yaw_error / NATIVE_YAW_SCALE_RAD).clamp(-0.4, 0.4),
            jaw: match waypoint.jaw {
                JawCommand::Open => 1.0,
                JawCommand::Close => -1.0,
            },
        }
    }

    fn is_done(&self) -> bool {
        self.current >= self.waypoints.len()
    }
}

/// Uniform random native commands from a seed (never done): a baseline that exercises the whole
/// command space, and a policy that task success predicates must reject.
#[derive(Clone, Debug)]
pub struct RandomPolicy {
    rng: crate::rng::SplitMix64,
}

impl RandomPolicy {
    pub fn new(seed: u64) -> Self {
        RandomPolicy {
            rng: crate::rng::SplitMix64::stream(seed, "random_policy"),
        }
    }
}

impl Policy for RandomPolicy {
    fn act(&mut self, _observation: &Observation) -> NativeCommand {
        let mut draw = || self.rng.uniform(-1.0, 1.0);
        NativeCommand {
            dx: draw(),
            dy: draw(),
            dz: draw(),
            dyaw: draw(),
            jaw: draw(),
        }
    }

    fn is_done(&self) -> bool {
        false
    }
}

/// Runs `first` until it is done, then `then`.
#[derive(Clone, Debug)]
pub struct Sequence<A, B> {
    pub first: A,
    pub then: B,
}

impl<A: Policy, B: Policy> Policy for Sequence<A, B> {
    fn act(&mut self, observation: &Observation) -> NativeCommand {
        if self.first.is_done() {
            self.then.act(observation)
        } else {
            self.first.act(observation)
        }
    }

    fn is_done(&self) -> bool {
        self.first.is_done() && self.then.is_done()
    }
}
