//! Declarative expert plans (`scripted_policies/*.toml`) and the planner that turns one into a
//! [`WaypointPolicy`] for a task instance.
//!
//! A plan lists waypoints relative to named frames of the instance:
//! - `pick`: the grasp point of the object the instruction names, yaw across its short side (or
//!   across a needle's wire);
//! - `place`: the top of the support object (T3-1's block) or the target mark (T3-2);
//! - `mark`: the target mark, yaw across the vessel at a clip site;
//! - `start`: the tip's start pose; `world`: the world origin.
//!
//! Per episode the planner draws, from the episode seed: a speed factor in `speed_factor`, one
//! offset per frame within `frame_jitter_m` (shared by every waypoint in that frame, so a
//! descend and its close stay together), an offset per waypoint within its `jitter_m`, a yaw
//! offset within `yaw_jitter_deg`, and, on steps toward waypoints with `noise = true`, with
//! probability `action_noise.probability`, a uniform disturbance of `action_noise.amplitude`
//! (native units, 1 = 1 cm) on the position command; the closed loop recovers from it, so the
//! data shows recoveries.

use crate::policy::waypoint::{Policy, Waypoint, WaypointPolicy};
use crate::rng::SplitMix64;
use crate::scene::{BLOCK_HALF_EXTENTS_M, ObjectKind};
use crate::sim::control::{JawCommand, NativeCommand};
use crate::sim::observation::Observation;
use crate::sim::psm::wrap_angle;
use crate::task::{TaskId, TaskInstance};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::{Path, PathBuf};

/// A frame waypoints are relative to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameName {
    Pick,
    Place,
    Mark,
    Start,
    World,
}

impl FrameName {
    /// The name as plan files write it.
    pub fn key(self) -> &'static str {
        match self {
            FrameName::Pick => "pick",
            FrameName::Place => "place",
            FrameName::Mark => "mark",
            FrameName::Start => "start",
            FrameName::World => "world",
        }
    }
}

/// How a waypoint's yaw is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum YawSpec {
    /// `"frame"` (the frame's crossing yaw, or hold when it has none) or `"hold"` (the previous
    /// waypoint's yaw).
    Named(YawKeyword),
    /// Absolute yaw, degrees.
    Degrees(f64),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum YawKeyword {
    Frame,
    Hold,
}

impl Default for YawSpec {
    fn default() -> Self {
        YawSpec::Named(YawKeyword::Hold)
    }
}

/// Jaw command of a waypoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JawSpec {
    Open,
    Close,
}

/// One waypoint of a plan file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointSpec {
    /// A label for reports and debugging.
    #[serde(default)]
    pub name: String,
    pub frame: FrameName,
    /// Offset from the frame's origin, world axes, metres.
    #[serde(default)]
    pub offset_m: [f64; 3],
    /// Per-episode uniform jitter of this waypoint alone (+-), metres.
    #[serde(default)]
    pub jitter_m: [f64; 3],
    #[serde(default)]
    pub yaw: YawSpec,
    pub jaw: JawSpec,
    /// Steps to stay once reached.
    #[serde(default)]
    pub hold_steps: u32,
    /// Multiplies the episode's speed factor toward this waypoint (below 1 for fine motions).
    #[serde(default = "one")]
    pub speed_scale: f64,
    /// Whether action noise may disturb the approach to this waypoint.
    #[serde(default = "yes")]
    pub noise: bool,
}

fn yes() -> bool {
    true
}

fn one() -> f64 {
    1.0
}

/// Action noise of a plan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionNoise {
    /// Chance per step of a disturbance.
    pub probability: f64,
    /// Largest disturbance per axis, native units (1 = 1 cm).
    pub amplitude: f64,
}

/// A task's expert plan as written in `scripted_policies/<task>.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpertPlan {
    /// Task name or id.
    pub task: String,
    /// Speed factor range `[low, high]` drawn per episode.
    pub speed_factor: [f64; 2],
    #[serde(default = "default_position_tolerance")]
    pub position_tolerance_m: f64,
    #[serde(default = "default_yaw_tolerance")]
    pub yaw_tolerance_rad: f64,
    #[serde(default)]
    pub yaw_jitter_deg: f64,
    #[serde(default)]
    pub action_noise: ActionNoise,
    /// Per-episode offset of each frame (+-), metres.
    #[serde(default)]
    pub frame_jitter_m: BTreeMap<FrameName, [f64; 3]>,
    #[serde(rename = "waypoint")]
    pub waypoints: Vec<WaypointSpec>,
}

fn default_position_tolerance() -> f64 {
    0.001
}

fn default_yaw_tolerance() -> f64 {
    0.1
}

/// A plan that cannot be read or used.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("reading {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("no expert plan for task {0}")]
    Missing(TaskId),
    #[error(
        "plan for {task}: waypoint {index} uses frame '{}', which this task does not have", frame.key()
    )]
    NoFrame {
        task: TaskId,
        index: usize,
        frame: FrameName,
    },
}

impl crate::error::HasKind for PlanError {
    /// A plan that cannot be read or used is the user's to fix (a custom plan folder), except a
    /// built-in plan the program lacks.
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            PlanError::Missing(_) => crate::error::ErrorKind::Failed,
            _ => crate::error::ErrorKind::Usage,
        }
    }
}

/// A frame resolved for one instance: origin and, if it has one, the yaw that crosses it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Frame {
    origin_m: [f64; 3],
    crossing_yaw_rad: Option<f64>,
}

/// The yaw at which the jaws (closing along the tip's local x) cross a line at `angle_rad`.
fn crossing_yaw(line_angle_rad: f64) -> f64 {
    wrap_angle(line_angle_rad + FRAC_PI_2)
}

fn frame(instance: &TaskInstance, start: &Observation, name: FrameName) -> Option<Frame> {
    let object_frame = |index: usize, top: bool| {
        let state = start.objects.get(index)?;
        let pose = state.world_from_object;
        let mut origin: [f64; 3] = pose.translation.vector.into();
        if top && state.kind == ObjectKind::Block {
            origin[2] += BLOCK_HALF_EXTENTS_M[2];
        }
        // The grasp frame's x is the needle's tangent at the grasp point: the jaws cross it
        // (as the binding rule requires); pads and blocks are taken the same way.
        let x_axis = pose.rotation * nalgebra::Vector3::x();
        Some(Frame {
            origin_m: origin,
            crossing_yaw_rad: Some(crossing_yaw(x_axis.y.atan2(x_axis.x))),
        })
    };
    let mark_frame = || {
        let mark = instance.scene.marks.get(instance.target_mark?)?;
        Some(Frame {
            origin_m: mark.position_m.into(),
            crossing_yaw_rad: mark.line_direction.map(|d| crossing_yaw(d.y.atan2(d.x))),
        })
    };
    match name {
        FrameName::Pick => object_frame(instance.target_object?, false),
        FrameName::Place => match instance.support_object {
            Some(support) => object_frame(support, true),
            None => mark_frame(),
        },
        FrameName::Mark => mark_frame(),
        FrameName::Start => Some(Frame {
            origin_m: start.tip_position_m,
            crossing_yaw_rad: None,
        }),
        FrameName::World => Some(Frame {
            origin_m: [0.0; 3],
            crossing_yaw_rad: None,
        }),
    }
}

/// The representative of the undirected line angle `yaw` (mod pi) closest to `reference`.
fn nearest_line_yaw(yaw: f64, reference: f64) -> f64 {
    let delta = wrap_angle(yaw - reference);
    let delta = if delta > FRAC_PI_2 {
        delta - PI
    } else if delta < -FRAC_PI_2 {
        delta + PI
    } else {
        delta
    };
    reference + delta
}

impl ExpertPlan {
    /// Parses a plan; `path` names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<ExpertPlan, PlanError> {
        let invalid = |message: String| PlanError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let plan: ExpertPlan = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        plan.task_id().map_err(|e| invalid(e.to_string()))?;
        let [low, high] = plan.speed_factor;
        if !(0.0 < low && low <= high && high <= 1.0) {
            return Err(invalid(format!(
                "speed_factor [{low}, {high}] must satisfy 0 < low <= high <= 1"
            )));
        }
        if let Some(bad) = plan
            .waypoints
            .iter()
            .find(|w| !(w.speed_scale > 0.0 && w.speed_scale <= 1.0 / high))
        {
            return Err(invalid(format!(
                "waypoint '{}': speed_scale {} must be in (0, 1 / speed_factor high]",
                bad.name, bad.speed_scale
            )));
        }
        if plan.waypoints.is_empty() {
            return Err(invalid("a plan needs at least one [[waypoint]]".into()));
        }
        let p = plan.action_noise.probability;
        if !(0.0..=1.0).contains(&p) || plan.action_noise.amplitude < 0.0 {
            return Err(invalid(
                "action_noise: probability in [0, 1], amplitude >= 0".into(),
            ));
        }
        plan.check_numbers().map_err(invalid)?;
        Ok(plan)
    }

    /// Every number finite and in a range a plan can mean (NaN, inf or 1e300 would parse and
    /// then fail every attempt): the key, its value and the range.
    fn check_numbers(&self) -> Result<(), String> {
        let check = |key: String, value: f64, (low, high): (f64, f64), unit: &str| {
            if value.is_finite() && (low..=high).contains(&value) {
                Ok(())
            } else {
                let shown = if value.is_finite() && (value.abs() >= 1e6 || value.abs() < 1e-4) {
                    format!("{value:e}")
                } else {
                    value.to_string()
                };
                Err(format!(
                    "{key} = {shown} must be a finite number in [{low}, {high}]{unit}"
                ))
            }
        };
        const OFFSET: (f64, f64) = (-0.5, 0.5);
        const JITTER: (f64, f64) = (0.0, 0.1);
        check(
            "position_tolerance_m".into(),
            self.position_tolerance_m,
            (1e-5, 0.05),
            " m",
        )?;
        check(
            "yaw_tolerance_rad".into(),
            self.yaw_tolerance_rad,
            (1e-4, PI),
            " rad",
        )?;
        check(
            "yaw_jitter_deg".into(),
            self.yaw_jitter_deg,
            (0.0, 180.0),
            " deg",
        )?;
        check(
            "action_noise.amplitude".into(),
            self.action_noise.amplitude,
            (0.0, 10.0),
            " (1 = 1 cm)",
        )?;
        for (frame, range) in &self.frame_jitter_m {
            for (axis, value) in range.iter().enumerate() {
                let key = format!("frame_jitter_m.{}[{axis}]", frame.key());
                check(key, *value, JITTER, " m")?;
            }
        }
        for (index, w) in self.waypoints.iter().enumerate() {
            let at = format!("waypoint {index} ('{}')", w.name);
            for axis in 0..3 {
                check(
                    format!("{at} offset_m[{axis}]"),
                    w.offset_m[axis],
                    OFFSET,
                    " m",
                )?;
                check(
                    format!("{at} jitter_m[{axis}]"),
                    w.jitter_m[axis],
                    JITTER,
                    " m",
                )?;
            }
            if let YawSpec::Degrees(yaw) = w.yaw {
                check(format!("{at} yaw"), yaw, (-360.0, 360.0), " deg")?;
            }
        }
        Ok(())
    }

    /// Whether every waypoint's frame exists in `instance`'s task (checked when a plan is
    /// loaded, so a wrong frame is the plan's error, not a failed episode).
    pub fn check_frames(&self, instance: &TaskInstance) -> Result<(), PlanError> {
        for (index, spec) in self.waypoints.iter().enumerate() {
            let exists = match spec.frame {
                FrameName::Pick => instance.target_object.is_some(),
                FrameName::Place => {
                    instance.support_object.is_some() || instance.target_mark.is_some()
                }
                FrameName::Mark => instance.target_mark.is_some(),
                FrameName::Start | FrameName::World => true,
            };
            if !exists {
                return Err(PlanError::NoFrame {
                    task: instance.task,
                    index,
                    frame: spec.frame,
                });
            }
        }
        Ok(())
    }

    /// The task the plan is for.
    pub fn task_id(&self) -> Result<TaskId, crate::task::UnknownTask> {
        self.task.parse()
    }

    /// The expert for one episode: waypoints resolved against `instance` as observed at the
    /// start, variation drawn from `seed`.
    pub fn expert(
        &self,
        instance: &TaskInstance,
        start: &Observation,
        seed: u64,
    ) -> Result<ExpertPolicy, PlanError> {
        let mut rng = SplitMix64::stream(seed, "expert");
        let speed = rng.uniform(self.speed_factor[0], self.speed_factor[1]);
        let yaw_jitter = rng
            .uniform(-self.yaw_jitter_deg, self.yaw_jitter_deg)
            .to_radians();
        let mut jitter = |range: [f64; 3]| range.map(|r| rng.uniform(-r, r));
        let frame_offsets: BTreeMap<FrameName, [f64; 3]> = [
            FrameName::Pick,
            FrameName::Place,
            FrameName::Mark,
            FrameName::Start,
            FrameName::World,
        ]
        .into_iter()
        .map(|name| {
            let range = self.frame_jitter_m.get(&name).copied().unwrap_or_default();
            (name, jitter(range))
        })
        .collect();
        let mut previous_yaw = start.tip_euler_xyz_rad[2];
        let mut waypoints = Vec::with_capacity(self.waypoints.len());
        let mut noisy = Vec::with_capacity(self.waypoints.len());
        for (index, spec) in self.waypoints.iter().enumerate() {
            let resolved = frame(instance, start, spec.frame).ok_or(PlanError::NoFrame {
                task: instance.task,
                index,
                frame: spec.frame,
            })?;
            let own = jitter(spec.jitter_m);
            let shared = frame_offsets[&spec.frame];
            let mut position_m = [0.0; 3];
            for axis in 0..3 {
                position_m[axis] =
                    resolved.origin_m[axis] + spec.offset_m[axis] + shared[axis] + own[axis];
            }
            let yaw_rad = match (spec.yaw, resolved.crossing_yaw_rad) {
                (YawSpec::Degrees(degrees), _) => degrees.to_radians(),
                (YawSpec::Named(YawKeyword::Frame), Some(yaw)) => {
                    nearest_line_yaw(yaw + yaw_jitter, previous_yaw)
                }
                _ => previous_yaw,
            };
            previous_yaw = yaw_rad;
            waypoints.push(Waypoint {
                position_m,
                yaw_rad,
                jaw: match spec.jaw {
                    JawSpec::Open => JawCommand::Open,
                    JawSpec::Close => JawCommand::Close,
                },
                hold_steps: spec.hold_steps,
                speed_scale: spec.speed_scale,
            });
            noisy.push(spec.noise);
        }
        let mut controller = WaypointPolicy::new(waypoints, speed);
        controller.position_tolerance_m = self.position_tolerance_m;
        controller.yaw_tolerance_rad = self.yaw_tolerance_rad;
        Ok(ExpertPolicy {
            controller,
            noisy,
            noise: self.action_noise,
            rng: SplitMix64::stream(seed, "expert_noise"),
        })
    }
}

/// A compiled expert: the waypoint controller plus seeded action noise.
#[derive(Clone, Debug)]
pub struct ExpertPolicy {
    controller: WaypointPolicy,
    noisy: Vec<bool>,
    noise: ActionNoise,
    rng: SplitMix64,
}

impl ExpertPolicy {
    /// The waypoint controller underneath.
    pub fn controller(&self) -> &WaypointPolicy {
        &self.controller
    }
}

impl Policy for ExpertPolicy {
    fn act(&mut self, observation: &Observation) -> NativeCommand {
        let mut command = self.controller.act(observation);
        // Draw every step so the noise sequence does not depend on which steps are noisy.
        let disturb = self.rng.next_f64() < self.noise.probability;
        let a = self.noise.amplitude;
        let offsets = [
            self.rng.uniform(-a, a),
            self.rng.uniform(-a, a),
            self.rng.uniform(-a, a),
        ];
        let noisy = self
            .noisy
            .get(self.controller.current_index())
            .copied()
            .unwrap_or(false);
        if disturb && noisy {
            command.dx += offsets[0];
            command.dy += offsets[1];
            command.dz += offsets[2];
        }
        command
    }

    fn is_done(&self) -> bool {
        self.controller.is_done()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_line_yaw_picks_the_closer_representative() {
        let close = nearest_line_yaw(-1.5, 1.5);
        assert!((close - (PI - 1.5)).abs() < 1e-12, "{close}");
        assert!((nearest_line_yaw(0.2, 0.0) - 0.2).abs() < 1e-12);
    }

    #[test]
    fn bad_plans_name_the_file_and_the_problem() {
        let path = Path::new("plans/x.toml");
        let error = ExpertPlan::parse("task = 'gauze_pik'\nspeed_factor = [0.5, 0.6]", path)
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("plans/x.toml") && error.contains("gauze_pik"),
            "{error}"
        );
        let error = ExpertPlan::parse(
            "task = 'gauze_pick'\nspeed_factor = [0.9, 0.6]\n[[waypoint]]\nframe = 'pick'\njaw = 'open'",
            path,
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("speed_factor"), "{error}");
        let error = ExpertPlan::parse(
            "task = 'gauze_pick'\nspeed_factor = [0.5, 0.6]\n[[waypoint]]\nframe = 'elsewhere'\njaw = 'open'",
            path,
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("elsewhere"), "{error}");
    }
}
