//! How far a trial got, and how it failed, from the simulator's state (not from the policy's
//! actions): a named chain of stages per task, the furthest stage reached, a progress score in
//! [0, 1], a failure class, and precision figures in millimetres (and a clip's angle in degrees).
//!
//! The chains (each stage latched once reached; success completes the chain):
//!
//! - pick (T1-1, T1-2, T2-1, T2-2): `reached` (the tip within [`REACH_RADIUS_M`] of the named
//!   object's grasp frame), `grasped` (that object held), `lifted` (the task's success);
//! - touch (T1-3): `reached` (the tip within [`REACH_RADIUS_M`] of the named mark), `touched`;
//! - clip (T2-3): `reached` (the named site), `jaws_around_vessel` (the tip came into the vessel
//!   from above, jaws straddling it, within [`REACH_RADIUS_M`] of the site), `clipped`;
//! - place (T3-1, T3-2): `reached`, `grasped`, `lifted` (the held object [`LIFT_M`] above where
//!   it lay), `transported` (held within [`OVER_TARGET_M`] of the target, horizontally),
//!   `released_on_target` (let go there), `settled` (the task's success).
//!
//! The failure class of a failed trial: `policy_error` (it did not answer), then the
//! terminal failures (`grasped_wrong_object`: a distractor; `unsafe`: a stab into an organ or a
//! jaw closure that damages the vessel; `dropped`: T3's object let fall or its support taken),
//! then by the stages: `never_reached`, `reached_no_grasp` (also a clip never closed),
//! `dropped` (the object let go on the way: before a pick held, or before it was over the
//! place's target), `released_off_target` (let go after it had been over the target, not on
//! it), and `timed_out` (still holding, or still on the way, when the steps ran out).

use crate::scene::{BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, OrganKind, OrganSpec, organ};
use crate::sim::Observation;
use crate::task::success::PENETRATION_LIMIT_M;
use crate::task::{TaskId, TaskInstance};
use nalgebra::{Isometry3, Vector3};

/// A stage's "near": the tip (or the held object) within 1 cm of its target.
pub const REACH_RADIUS_M: f64 = 0.01;
/// A held object counts as lifted 5 mm above where it lay.
pub const LIFT_M: f64 = 0.005;
/// A held object counts as over its target within 1 cm horizontally.
pub const OVER_TARGET_M: f64 = 0.01;
/// The tip touches tissue within 1 mm of an organ's surface (or inside it, or inside the
/// vessel).
pub const CONTACT_M: f64 = 0.001;
/// A contact within 4 mm of the named mark is on target (the touch and clip tolerance).
pub const ON_TARGET_M: f64 = 0.004;

/// Why a trial failed, by class.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum FailureClass {
    PolicyError,
    NeverReached,
    ReachedNoGrasp,
    GraspedWrongObject,
    Dropped,
    ReleasedOffTarget,
    TimedOut,
    Unsafe,
}

impl FailureClass {
    /// Every class, in the order results list them.
    pub const ALL: [FailureClass; 8] = [
        FailureClass::NeverReached,
        FailureClass::ReachedNoGrasp,
        FailureClass::GraspedWrongObject,
        FailureClass::Dropped,
        FailureClass::ReleasedOffTarget,
        FailureClass::TimedOut,
        FailureClass::Unsafe,
        FailureClass::PolicyError,
    ];

    /// Its name in results.
    pub fn name(self) -> &'static str {
        match self {
            FailureClass::PolicyError => "policy_error",
            FailureClass::NeverReached => "never_reached",
            FailureClass::ReachedNoGrasp => "reached_no_grasp",
            FailureClass::GraspedWrongObject => "grasped_wrong_object",
            FailureClass::Dropped => "dropped",
            FailureClass::ReleasedOffTarget => "released_off_target",
            FailureClass::TimedOut => "timed_out",
            FailureClass::Unsafe => "unsafe",
        }
    }
}

/// A stage's or event's name: one of a fixed few (an alias, so that serde's derive reads it
/// through the `deserialize_with` given rather than borrowing it from the input).
pub type Name = &'static str;

/// A stage's name as read back (a resumed evaluation's journal): one of the chains' names.
fn known_stage<'de, D: serde::Deserializer<'de>>(d: D) -> Result<&'static str, D::Error> {
    let name = <std::borrow::Cow<'de, str> as serde::Deserialize>::deserialize(d)?;
    std::iter::once("none")
        .chain(
            TaskId::ALL
                .into_iter()
                .flat_map(|t| stages(t).iter().copied()),
        )
        .find(|s| *s == name)
        .ok_or_else(|| serde::de::Error::custom(format!("no stage is named {name:?}")))
}

/// The stages of `task`, in order.
pub fn stages(task: TaskId) -> &'static [&'static str] {
    match task {
        TaskId::GauzePick
        | TaskId::NeedlePick
        | TaskId::GauzePickDistractors
        | TaskId::NeedlePickDistractors => &["reached", "grasped", "lifted"],
        TaskId::Electrocoagulation => &["reached", "touched"],
        TaskId::VesselClipping => &["reached", "jaws_around_vessel", "clipped"],
        TaskId::PickAndPlace | TaskId::Hemostasis => &[
            "reached",
            "grasped",
            "lifted",
            "transported",
            "released_on_target",
            "settled",
        ],
    }
}

/// What a trial reached, and its precision figures.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrialProgress {
    /// The furthest stage reached ("none" before the first).
    #[serde(deserialize_with = "known_stage")]
    pub stage: Name,
    /// Stages reached / stages of the task, in [0, 1]; 1 exactly on success.
    pub progress: f64,
    /// Why it failed (None on success).
    pub failure_class: Option<FailureClass>,
    /// The tip's distance from the named object's grasp frame (the gauze's centre, the needle's
    /// midpoint) when the object was first held, mm.
    pub grasp_offset_mm: Option<f64>,
    /// T3-1 and T3-2: the object's horizontal distance from its target at the end, mm.
    pub placement_error_mm: Option<f64>,
    /// The tool tip's path, mm.
    pub path_length_mm: f64,
    /// Seconds to success (None: no success).
    pub time_to_success_s: Option<f64>,
    /// T2-3: how far the jaws' line was from crossing the vessel when they first closed in it,
    /// degrees (0: straight across).
    pub clip_angle_error_deg: Option<f64>,
    /// T3-1 and T3-2: the share of the target (the block's top; a 1 cm disc around the bleeding
    /// site) under the object's footprint at the end, when it lies there, percent.
    pub covered_fraction_pct: Option<f64>,
    /// Times the tip came into contact with tissue (an organ's surface, the vessel) farther
    /// than [`ON_TARGET_M`] from the named mark, or anywhere when nothing is to be touched;
    /// sampled every control step.
    pub tissue_contacts_off_target: u32,
}

/// Watches a trial step by step.
#[derive(Clone, Debug)]
pub struct ProgressTracker {
    task: TaskId,
    target: Option<usize>,
    /// Where the named object lay at the start (pick and place).
    start_z_m: f64,
    /// The named mark (touch, clip; T3-2's place).
    mark_m: Option<Vector3<f64>>,
    support: Option<usize>,
    /// Latched stage flags, in chain order (the last, success, is set at the end).
    reached: Vec<bool>,
    last_tip_m: Vector3<f64>,
    path_m: f64,
    grasp_offset_m: Option<f64>,
    organs: Vec<OrganSpec>,
    in_contact: bool,
    contacts_off_target: u32,
}

/// Rounded to the micrometre: the figure, not float noise.
fn mm(metres: f64) -> f64 {
    (metres * 1e6).round() / 1e3
}

impl ProgressTracker {
    /// Starts watching `instance` from its first observation.
    pub fn new(instance: &TaskInstance, first: &Observation) -> Self {
        let target = instance.target_object;
        let start_z_m = (target.and_then(|i| first.objects.get(i)))
            .map_or(0.0, |o| o.world_from_object.translation.z);
        let mut tracker = ProgressTracker {
            task: instance.task,
            target,
            start_z_m,
            mark_m: target_mark_m(instance),
            support: instance.support_object,
            reached: vec![false; stages(instance.task).len()],
            last_tip_m: Vector3::from(first.tip_position_m),
            path_m: 0.0,
            grasp_offset_m: None,
            organs: instance.scene.organs.clone(),
            in_contact: false,
            contacts_off_target: 0,
        };
        tracker.update(first);
        tracker
    }

    fn place_m(&self, observation: &Observation) -> Option<Vector3<f64>> {
        place_target_m(self.support, self.mark_m, observation)
    }

    /// Takes one step's observation.
    pub fn update(&mut self, observation: &Observation) {
        let tip = Vector3::from(observation.tip_position_m);
        self.path_m += (tip - self.last_tip_m).norm();
        self.last_tip_m = tip;
        self.count_contact(&tip);
        let near = |p: Vector3<f64>| (tip - p).norm() <= REACH_RADIUS_M;
        let object = self.target.and_then(|i| observation.objects.get(i));
        // Holding the object means the tip got there, wherever on it the jaws closed.
        let reach = match object {
            Some(o) => near(o.world_from_object.translation.vector) || o.ever_bound,
            None => self.mark_m.is_some_and(near),
        };
        self.latch(0, reach);
        if self.task == TaskId::VesselClipping {
            let around = (observation.history.vessel_entries.iter())
                .any(|e| e.from_above && self.mark_m.is_some_and(|m| near_to(e.tip_m, m)));
            self.latch(1, around);
            return;
        }
        let Some(object) = object else {
            return;
        };
        let position = object.world_from_object.translation.vector;
        let held = object.bound;
        if held && self.grasp_offset_m.is_none() {
            self.grasp_offset_m = Some((tip - position).norm());
        }
        self.latch(1, object.ever_bound);
        if !matches!(self.task, TaskId::PickAndPlace | TaskId::Hemostasis) {
            return;
        }
        self.latch(2, held && position.z - self.start_z_m >= LIFT_M);
        let over = self
            .place_m(observation)
            .is_some_and(|p| (position - p).xy().norm() <= OVER_TARGET_M);
        self.latch(3, held && over);
        let released = object.released_at.is_some() && !held;
        self.latch(4, released && over);
    }

    /// Counts the tip's arrival on tissue away from the named mark.
    fn count_contact(&mut self, tip: &Vector3<f64>) {
        let touching = self.organs.iter().any(|o| match o.kind {
            OrganKind::Vessel => organ::vessel_section(o, tip).inside(),
            _ => organ::radial_gap_m(o, tip) <= CONTACT_M,
        });
        let on_target = self.mark_m.is_some_and(|m| (tip - m).norm() <= ON_TARGET_M);
        if touching && !self.in_contact && !on_target {
            self.contacts_off_target += 1;
        }
        self.in_contact = touching;
    }

    /// T3's covered share of the target at the end (None for other tasks, or when the object is
    /// held or not lying at the target's height).
    fn covered_pct(&self, last: &Observation) -> Option<f64> {
        if !matches!(self.task, TaskId::PickAndPlace | TaskId::Hemostasis) {
            return None;
        }
        let object = self.target.and_then(|i| last.objects.get(i))?;
        let gauze: Isometry3<f64> = object.world_from_object;
        // The target's samples: the block's top face, or a disc around the bleeding site.
        let (samples, top_z) = match self.support.and_then(|i| last.objects.get(i)) {
            Some(block) => {
                let pose = block.world_from_object;
                let [hx, hy, hz] = BLOCK_HALF_EXTENTS_M;
                let points: Vec<Vector3<f64>> = grid(16)
                    .map(|(u, v)| pose * nalgebra::Point3::new(u * hx, v * hy, hz))
                    .map(|p| p.coords)
                    .collect();
                (points, (pose.translation.z + hz))
            }
            None => {
                let mark = self.mark_m?;
                let r = OVER_TARGET_M;
                let points: Vec<Vector3<f64>> = grid(16)
                    .filter(|(u, v)| u * u + v * v <= 1.0)
                    .map(|(u, v)| mark + Vector3::new(u * r, v * r, 0.0))
                    .collect();
                (points, mark.z)
            }
        };
        if object.bound || (gauze.translation.z - top_z).abs() > REACH_RADIUS_M {
            return Some(0.0);
        }
        let [hx, hy, _] = GAUZE_HALF_EXTENTS_M;
        let inverse = gauze.inverse();
        let covered = (samples.iter())
            .filter(|p| {
                let local = inverse * nalgebra::Point3::from(**p);
                local.x.abs() <= hx && local.y.abs() <= hy
            })
            .count();
        let pct = 100.0 * covered as f64 / samples.len().max(1) as f64;
        Some((pct * 10.0).round() / 10.0)
    }

    /// Sets stage `index` once the ones before it are set.
    fn latch(&mut self, index: usize, now: bool) {
        let ready = index == 0 || self.reached.get(index - 1).copied().unwrap_or(false);
        if let Some(flag) = self.reached.get_mut(index) {
            *flag |= now && ready;
        }
    }

    /// The trial's progress after `steps` control steps of `dt_secs`, with its final
    /// observation and verdict.
    pub fn finish(
        &self,
        instance: &TaskInstance,
        last: &Observation,
        success: bool,
        policy_error: bool,
        (steps, dt_secs): (u32, f64),
    ) -> TrialProgress {
        let chain = stages(self.task);
        let count = if success {
            chain.len()
        } else {
            self.reached.iter().take_while(|r| **r).count()
        };
        let placement = (matches!(self.task, TaskId::PickAndPlace | TaskId::Hemostasis))
            .then(|| {
                let object = self.target.and_then(|i| last.objects.get(i))?;
                let place = self.place_m(last)?;
                Some(mm((object.world_from_object.translation.vector - place)
                    .xy()
                    .norm()))
            })
            .flatten();
        TrialProgress {
            stage: count.checked_sub(1).map_or("none", |i| chain[i]),
            progress: count as f64 / chain.len() as f64,
            failure_class: (!success).then(|| self.class(instance, last, policy_error)),
            grasp_offset_mm: self.grasp_offset_m.map(mm),
            placement_error_mm: placement,
            path_length_mm: mm(self.path_m),
            time_to_success_s: success.then(|| f64::from(steps) * dt_secs),
            clip_angle_error_deg: (last.history.vessel_closures.first())
                .and_then(|c| instance.off_crossing_rad(&c.tip_m, c.jaw_line_rad))
                .map(|rad| (rad.to_degrees() * 1e3).round() / 1e3),
            covered_fraction_pct: self.covered_pct(last),
            tissue_contacts_off_target: self.contacts_off_target,
        }
    }

    fn class(
        &self,
        instance: &TaskInstance,
        last: &Observation,
        policy_error: bool,
    ) -> FailureClass {
        if policy_error {
            return FailureClass::PolicyError;
        }
        let distractor = (last.objects.iter().zip(&instance.scene.objects))
            .any(|(state, spec)| spec.distractor && state.ever_bound);
        if distractor {
            return FailureClass::GraspedWrongObject;
        }
        if last.history.peak_penetration_m > PENETRATION_LIMIT_M {
            return FailureClass::Unsafe;
        }
        if instance.terminal_failure(last).is_some() {
            return match self.task {
                TaskId::VesselClipping => FailureClass::Unsafe,
                _ => FailureClass::Dropped,
            };
        }
        let (reached, second) = (self.reached[0], self.reached.get(1).copied());
        if !reached {
            return FailureClass::NeverReached;
        }
        match self.task {
            TaskId::Electrocoagulation => return FailureClass::TimedOut,
            TaskId::VesselClipping => return FailureClass::ReachedNoGrasp,
            _ => {}
        }
        if second != Some(true) {
            return FailureClass::ReachedNoGrasp;
        }
        let held = (self.target.and_then(|i| last.objects.get(i))).is_some_and(|o| o.bound);
        // Let go on the way is a drop; let go once it had been over the target, a release off it.
        let transported = self.reached.get(3).copied().unwrap_or(false);
        match (held, transported) {
            (true, _) => FailureClass::TimedOut,
            (false, true) => FailureClass::ReleasedOffTarget,
            (false, false) => FailureClass::Dropped,
        }
    }
}

/// The named mark's position (T1-3's spot, T2-3's clip site, T3-2's bleeding site).
pub(super) fn target_mark_m(instance: &TaskInstance) -> Option<Vector3<f64>> {
    (instance.target_mark)
        .and_then(|i| instance.scene.marks.get(i))
        .map(|m| m.position_m)
}

/// Where a held object goes: the support object where it is now (T3-1's block), else the
/// named mark (T3-2's bleeding site).
pub(super) fn place_target_m(
    support: Option<usize>,
    mark_m: Option<Vector3<f64>>,
    observation: &Observation,
) -> Option<Vector3<f64>> {
    (support.and_then(|i| observation.objects.get(i)))
        .map(|o| o.world_from_object.translation.vector)
        .or(mark_m)
}

/// An n x n grid of cell centres over [-1, 1]^2.
fn grid(n: usize) -> impl Iterator<Item = (f64, f64)> {
    let at = move |i: usize| (2.0 * i as f64 + 1.0) / n as f64 - 1.0;
    (0..n).flat_map(move |i| (0..n).map(move |j| (at(i), at(j))))
}

fn near_to(a: [f64; 3], b: Vector3<f64>) -> bool {
    (Vector3::from(a) - b).norm() <= REACH_RADIUS_M
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::{Env, EnvOptions};
    use crate::policy::{ExpertLibrary, Policy};
    use crate::sim::NativeCommand;

    /// A trial driven by `policy` (given the step, the expert's command and the tracker so far)
    /// as `eval` runs one: until success, a terminal failure or the step limit.
    fn trial(
        task: TaskId,
        seed: u64,
        plan_for: fn(&TaskInstance) -> TaskInstance,
        mut policy: impl FnMut(u32, NativeCommand, &ProgressTracker, &Observation) -> NativeCommand,
    ) -> TrialProgress {
        let library = ExpertLibrary::builtin().expect("plans");
        let (mut env, first) = Env::reset(task, seed, &EnvOptions::headless()).expect("spawn");
        let instance = env.instance().clone();
        let planned = plan_for(&instance);
        let plan = library.plan(task).expect("plan");
        let mut expert = plan.expert(&planned, &first.sim, seed).expect("expert");
        let mut tracker = ProgressTracker::new(&instance, &first.sim);
        let mut observation = first.sim;
        let mut success = false;
        while env.steps() < env.max_steps() {
            let command = policy(
                env.steps(),
                expert.act(&observation),
                &tracker,
                &observation,
            );
            let step = env.step_native(&command);
            tracker.update(&step.observation.sim);
            observation = step.observation.sim;
            success = step.verdict.success;
            if step.done {
                break;
            }
        }
        tracker.finish(&instance, &observation, success, false, (env.steps(), 0.2))
    }

    fn same(instance: &TaskInstance) -> TaskInstance {
        instance.clone()
    }

    fn expert(
        _: u32,
        command: NativeCommand,
        _: &ProgressTracker,
        _: &Observation,
    ) -> NativeCommand {
        command
    }

    #[test]
    fn the_expert_completes_every_chain() {
        for task in TaskId::ALL {
            let p = trial(task, 5, same, expert);
            assert_eq!((p.progress, p.failure_class), (1.0, None), "{task}: {p:?}");
            assert_eq!(p.stage, *stages(task).last().expect("stages"), "{task}");
            assert!(
                p.time_to_success_s.is_some() && p.path_length_mm > 10.0,
                "{task}"
            );
            assert_eq!(
                p.tissue_contacts_off_target, 0,
                "{task}: the expert touches only its mark"
            );
            let covered = p.covered_fraction_pct;
            match task {
                TaskId::PickAndPlace | TaskId::Hemostasis => {
                    assert!(covered.is_some_and(|pct| pct > 30.0), "{task}: {covered:?}")
                }
                _ => assert_eq!(covered, None),
            }
            let clip = p.clip_angle_error_deg;
            match task {
                TaskId::VesselClipping => assert!(clip.is_some_and(|deg| deg < 20.0), "{clip:?}"),
                _ => assert_eq!(clip, None, "{task}"),
            }
        }
    }

    fn open(c: NativeCommand) -> NativeCommand {
        NativeCommand { jaw: 1.0, ..c }
    }

    /// Straight to the first distractor: above it, down onto it, close.
    fn grab_distractor(
        step: u32,
        _: NativeCommand,
        _: &ProgressTracker,
        o: &Observation,
    ) -> NativeCommand {
        let index = o.objects.iter().position(|x| x.name.contains("distractor"));
        let Some(target) = index.and_then(|i| o.objects.get(i)) else {
            return NativeCommand::default();
        };
        let goal = target.world_from_object.translation.vector;
        let tip = Vector3::from(o.tip_position_m);
        // The jaws across the needle's wire: its tangent at the midpoint (the grasp frame's x
        // axis) along the tip's yaw + 90 deg, as the binding rule asks.
        let tangent = target.world_from_object.rotation * Vector3::x();
        let yaw = tangent.y.atan2(tangent.x) - std::f64::consts::FRAC_PI_2;
        let turn = crate::sim::psm::wrap_angle(yaw - o.tip_euler_xyz_rad[2]);
        let turn = crate::sim::psm::wrap_angle(2.0 * turn) / 2.0;
        let above = if (tip - goal).xy().norm() > 0.001 || turn.abs() > 0.05 {
            0.01
        } else {
            0.0
        };
        let d = (goal + Vector3::new(0.0, 0.0, above) - tip) / 0.01;
        let close = above == 0.0 && d.norm() < 0.05 || step > 60;
        NativeCommand {
            dx: d.x.clamp(-1.0, 1.0),
            dy: d.y.clamp(-1.0, 1.0),
            dz: d.z.clamp(-1.0, 1.0),
            dyaw: (turn / (std::f64::consts::PI / 6.0)).clamp(-1.0, 1.0),
            jaw: if close { -1.0 } else { 1.0 },
        }
    }

    /// The expert until the object is held, then the jaws open.
    fn release_early(
        _: u32,
        c: NativeCommand,
        t: &ProgressTracker,
        _: &Observation,
    ) -> NativeCommand {
        if t.reached[1] { open(c) } else { c }
    }

    /// The expert until the mark is reached, then straight down into the organ.
    fn stab(_: u32, c: NativeCommand, t: &ProgressTracker, _: &Observation) -> NativeCommand {
        if t.reached[0] {
            NativeCommand {
                dz: -1.0,
                ..NativeCommand::default()
            }
        } else {
            c
        }
    }

    /// The held-out probe: policies with planted failure modes, each over 20 scenes, land in
    /// their failure class and stage in at least 95 % of their trials.
    #[test]
    fn planted_failure_modes_are_classified() {
        type Planted = fn(u32, NativeCommand, &ProgressTracker, &Observation) -> NativeCommand;
        let idle: Planted = |_, _, _, _| open(NativeCommand::default());
        let never_close: Planted = |_, c, _, _| open(c);
        let probes: [(&str, TaskId, Planted, FailureClass, &str); 6] = [
            (
                "idle",
                TaskId::GauzePick,
                idle,
                FailureClass::NeverReached,
                "none",
            ),
            (
                "reach, never close",
                TaskId::NeedlePick,
                never_close,
                FailureClass::ReachedNoGrasp,
                "reached",
            ),
            (
                "grasp the distractor",
                TaskId::GauzePickDistractors,
                grab_distractor,
                FailureClass::GraspedWrongObject,
                "none",
            ),
            (
                "release early",
                TaskId::GauzePick,
                release_early,
                FailureClass::Dropped,
                "grasped",
            ),
            (
                "release early",
                TaskId::PickAndPlace,
                release_early,
                FailureClass::Dropped,
                "grasped",
            ),
            (
                "stab the tissue",
                TaskId::Electrocoagulation,
                stab,
                FailureClass::Unsafe,
                "reached",
            ),
        ];
        for (name, task, policy, class, stage) in probes {
            let trials: Vec<TrialProgress> = (0..20)
                .map(|seed| trial(task, seed, same, policy))
                .collect();
            let right = (trials.iter())
                .filter(|p| p.failure_class == Some(class) && p.stage == stage)
                .count();
            let wrong: Vec<_> = (trials.iter())
                .filter(|p| p.failure_class != Some(class) || p.stage != stage)
                .map(|p| (p.failure_class, p.stage))
                .collect();
            assert!(
                right >= 19,
                "{name} on {task}: {right} of 20 right; the others {wrong:?}"
            );
            if class == FailureClass::Dropped {
                assert!(
                    trials
                        .iter()
                        .all(|p| p.grasp_offset_mm.is_some_and(|mm| mm < 10.0))
                );
            }
        }
    }

    /// Touching the kidney 12 mm beside the spot: one contact off target, never reached.
    #[test]
    fn a_touch_beside_the_spot_is_a_contact_off_target() {
        let beside = trial(TaskId::Electrocoagulation, 2, same, |_, _, t, o| {
            let aim = t.mark_m.expect("a mark") + Vector3::new(0.012, 0.0, 0.0);
            let tip = Vector3::from(o.tip_position_m);
            if t.contacts_off_target > 0 {
                return NativeCommand::default();
            }
            let d = if (aim - tip).xy().norm() > 0.001 {
                (aim + Vector3::new(0.0, 0.0, 0.015) - tip) / 0.01
            } else {
                Vector3::new(0.0, 0.0, -0.2)
            };
            NativeCommand {
                dx: d.x.clamp(-1.0, 1.0),
                dy: d.y.clamp(-1.0, 1.0),
                dz: d.z.clamp(-1.0, 1.0),
                jaw: -1.0,
                ..NativeCommand::default()
            }
        });
        assert_eq!(beside.tissue_contacts_off_target, 1, "{beside:?}");
        assert_eq!(beside.failure_class, Some(FailureClass::NeverReached));
    }

    /// The expert's commands replayed open loop, the whole path shifted 3 mm along x at the
    /// start: the grasp lands off centre by about that much.
    #[test]
    fn a_shifted_replay_shows_in_the_grasp_offset() {
        let mut played = Vec::new();
        let honest = trial(TaskId::GauzePick, 4, same, |_, c, _, _| {
            played.push(c);
            c
        });
        // The first command with room for 3 mm more along x (commands saturate at 1 cm).
        let at = played
            .iter()
            .position(|c| c.dx.abs() < 0.6)
            .expect("a slow step");
        let shifted = trial(TaskId::GauzePick, 4, same, |step, _, _, _| {
            let mut c = played.get(step as usize).copied().unwrap_or_default();
            if step as usize == at {
                c.dx += 0.3;
            }
            c
        });
        let (a, b) = (
            honest.grasp_offset_mm.expect("held"),
            shifted.grasp_offset_mm.expect("held"),
        );
        assert!(b > a + 2.0, "honest {a} mm, shifted {b} mm");
        assert!(shifted.path_length_mm > 10.0 && honest.failure_class.is_none());
    }
}
