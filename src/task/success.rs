//! Success predicates: whether a trial, as its observation and history (`sim::history`)
//! record it, completes the task of a [`TaskInstance`]. Each judges the physical event, and
//! each condition at the moment it matters (rule set [`RULE_SET`]; docs/FIDELITY.md gives
//! every rule with a motion that passes and one that fails):
//!
//! | task | success |
//! |---|---|
//! | T1-1, T2-1 | the named gauze bound (the jaws closed on its top face: see `sim::grasp`) and raised >= 10 mm |
//! | T1-2, T2-2 | the named needle bound (the jaws closed on its wire, across it within 45 deg, not past its ends), raised >= 4 mm, not touching the tray |
//! | T2-1, T2-2 | ... and no distractor ever grasped (a terminal failure: the trial ends there) or moved more than 2 mm |
//! | T1-3 | jaws closed, the tip on the organ's surface (within 1 mm of it, either side) on the drawn spot (within its radius) |
//! | T2-3 | a clip applied at the named site (`clip_rule`): the jaws entered the vessel open, across it, from above, closed in the band around the site, across the vessel when they closed |
//! | T3-1 | the gauze placed (`place_rule`): every release within 5 mm above what was under it, the block never held and not moved since, the gauze at rest with its centre over the block's top, gap < 3 mm |
//! | T3-2 | the gauze placed: every release within 5 mm above what was under it, the spot wholly under the footprint when let go and within 3 mm of it after sliding, resting on the spleen |
//!
//! Every task: the tip never deeper than [`PENETRATION_LIMIT_M`] inside a kidney or spleen
//! (a terminal failure). Terminal failures end a trial the moment they happen
//! ([`TaskInstance::terminal_failure`]); every verdict carries a short reason, so a failed
//! episode says why.

use crate::scene::{ObjectKind, OrganKind, OrganSpec, organ};
use crate::sim::JAWS_CLOSED_RAD;
use crate::sim::observation::Observation;
use crate::task::id::TaskId;
use crate::task::spawn::TaskInstance;
use nalgebra::Vector3;

/// The name and version of these rules, recorded with every dataset and evaluation: a dataset
/// judged by other rules is not re-judged by these.
pub const RULE_SET: &str = "surgvla-physical-v2";

/// Lift a picked gauze needs, metres.
pub const GAUZE_LIFT_M: f64 = 0.010;
/// Lift a picked needle needs, metres.
pub const NEEDLE_LIFT_M: f64 = 0.004;
/// Largest distance between the touching tip and the organ's surface, either side, metres:
/// on the tissue, neither hovering over it nor pushed into it.
pub const TOUCH_SURFACE_GAP_M: f64 = 0.001;
/// Deepest the tool tip may go below a kidney's or spleen's surface at any time, metres:
/// twice the touch's allowance; deeper is a stab, whatever the tip does next.
pub const PENETRATION_LIMIT_M: f64 = 0.002;

/// The outcome of a success check.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    pub success: bool,
    /// What held or what was missing, e.g. "gauze raised 3.1 mm < 10 mm".
    pub reason: String,
}

impl Verdict {
    pub(super) fn pass(reason: impl Into<String>) -> Self {
        Verdict {
            success: true,
            reason: reason.into(),
        }
    }

    pub(super) fn fail(reason: impl Into<String>) -> Self {
        Verdict {
            success: false,
            reason: reason.into(),
        }
    }
}

/// The failure of a task that needs closed jaws, when they are open.
fn jaws_open(observation: &Observation) -> Option<Verdict> {
    (observation.jaw_angle_rad > JAWS_CLOSED_RAD).then(|| {
        Verdict::fail(format!(
            "jaws open ({:.0} deg)",
            observation.jaw_angle_rad.to_degrees()
        ))
    })
}

impl TaskInstance {
    /// The solid organ a mark lies on: the one whose surface passes nearest it.
    pub(super) fn organ_under(&self, mark_m: &Vector3<f64>) -> Option<&OrganSpec> {
        let at_mark = |o: &OrganSpec| organ::radial_gap_m(o, mark_m).abs();
        self.scene
            .organs
            .iter()
            .filter(|o| o.kind != OrganKind::Vessel)
            .min_by(|a, b| at_mark(a).total_cmp(&at_mark(b)))
    }

    /// A failure that ends a trial (or an expert attempt) the moment it happens, whatever
    /// follows: a distractor grasped (T2-1, T2-2); the tip deeper than
    /// [`PENETRATION_LIMIT_M`] in a kidney or spleen; the jaws into the vessel closed,
    /// through its wall or along it, or closed in it anywhere but at the named site (T2-3); the gauze
    /// dropped, or its support held (T3-1, T3-2).
    pub fn terminal_failure(&self, observation: &Observation) -> Option<Verdict> {
        if let Some((_, spec)) = observation
            .objects
            .iter()
            .zip(&self.scene.objects)
            .find(|(state, spec)| spec.distractor && state.ever_bound)
        {
            return Some(Verdict::fail(format!(
                "grasped the distractor '{}'",
                spec.name
            )));
        }
        let depth = observation.history.peak_penetration_m;
        if depth > PENETRATION_LIMIT_M {
            return Some(Verdict::fail(format!(
                "the tip went {:.1} mm into the tissue (deeper than {:.0} mm is a stab)",
                depth * 1e3,
                PENETRATION_LIMIT_M * 1e3
            )));
        }
        self.vessel_decision(observation)
            .filter(|verdict| !verdict.success)
            .or_else(|| self.placement_failure(observation))
    }

    /// Whether `observation` completes this instance's task.
    pub fn success(&self, observation: &Observation) -> Verdict {
        if let Some(failure) = self.terminal_failure(observation) {
            return failure;
        }
        match self.task {
            TaskId::GauzePick
            | TaskId::NeedlePick
            | TaskId::GauzePickDistractors
            | TaskId::NeedlePickDistractors => self.picked(observation),
            TaskId::Electrocoagulation => self.touched(observation),
            TaskId::VesselClipping => self.clipped(observation),
            TaskId::PickAndPlace => self.placed_on_block(observation),
            TaskId::Hemostasis => self.placed_on_mark(observation),
        }
    }

    fn picked(&self, observation: &Observation) -> Verdict {
        let Some(target) = self.target_object else {
            return Verdict::fail("no target object");
        };
        let spec = &self.scene.objects[target];
        let Some(state) = observation.objects.get(target) else {
            return Verdict::fail("target object missing from the observation");
        };
        if observation.bound_object != Some(target) {
            return match observation.bound_object {
                Some(other) => Verdict::fail(format!(
                    "holding '{}', not '{}'",
                    self.scene.objects[other].name, spec.name
                )),
                None => Verdict::fail(format!("'{}' not held", spec.name)),
            };
        }
        let lift = state.world_from_object.translation.z - spec.world_from_object.translation.z;
        let needed = if spec.kind == ObjectKind::Needle {
            NEEDLE_LIFT_M
        } else {
            GAUZE_LIFT_M
        };
        if lift < needed {
            return Verdict::fail(format!(
                "'{}' raised {:.1} mm < {:.0} mm",
                spec.name,
                lift * 1e3,
                needed * 1e3
            ));
        }
        if spec.kind == ObjectKind::Needle && state.on_tray {
            return Verdict::fail("needle still touches the tray");
        }
        if let Some(moved) = observation
            .objects
            .iter()
            .zip(&self.scene.objects)
            .find(|(state, spec)| spec.distractor && state.moved)
        {
            return Verdict::fail(format!(
                "distractor '{}' moved {:.1} mm",
                moved.1.name,
                moved.0.displacement_m * 1e3
            ));
        }
        Verdict::pass(format!("'{}' held {:.1} mm up", spec.name, lift * 1e3))
    }

    fn touched(&self, observation: &Observation) -> Verdict {
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
            return Verdict::fail("no target mark");
        };
        let tip = Vector3::from(observation.tip_position_m);
        if let Some(open) = jaws_open(observation) {
            return open;
        }
        let Some(organ) = self.organ_under(&mark.position_m) else {
            return Verdict::fail("no tissue to touch");
        };
        let gap = organ::radial_gap_m(organ, &tip);
        // On the drawn spot: the tip's distance from its centre along the surface (the part of
        // the offset across the ray from the organ's centre, which the gap measures along).
        let normal = (mark.position_m - organ.world_from_organ.translation.vector).normalize();
        let offset = tip - mark.position_m;
        let distance = (offset - normal * offset.dot(&normal)).norm();
        if distance > mark.radius_m {
            return Verdict::fail(format!(
                "tip {:.1} mm from the centre of '{}' (off the drawn spot, {:.1} mm in radius)",
                distance * 1e3,
                mark.name,
                mark.radius_m * 1e3
            ));
        }
        if gap.abs() > TOUCH_SURFACE_GAP_M {
            return Verdict::fail(format!(
                "tip {:.1} mm {} the tissue's surface (touching is within {:.0} mm of it)",
                gap.abs() * 1e3,
                if gap > 0.0 { "above" } else { "inside" },
                TOUCH_SURFACE_GAP_M * 1e3
            ));
        }
        Verdict::pass(format!(
            "tip on the tissue ({:+.1} mm) {:.1} mm from '{}'",
            gap * 1e3,
            distance * 1e3,
            mark.name
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimConfig, Simulator};
    use crate::task::spawn::TaskConfig;

    #[test]
    fn no_task_is_done_at_the_start() {
        for task in TaskId::ALL {
            for seed in 0..5 {
                let instance = task.instance(seed, &TaskConfig::default()).unwrap();
                let sim = Simulator::new(SimConfig::default(), instance.scene.clone());
                let verdict = instance.success(&sim.observation());
                assert!(!verdict.success, "{task} seed {seed}: {}", verdict.reason);
                assert!(!verdict.reason.is_empty());
            }
        }
    }
}
