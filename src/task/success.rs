//! Success predicates: whether an observation completes the task of a [`TaskInstance`].
//!
//! | task | success |
//! |---|---|
//! | T1-1, T2-1 | the named gauze bound and raised >= 10 mm |
//! | T1-2, T2-2 | the named needle bound, raised >= 4 mm, not touching the tray |
//! | T2-1, T2-2 | ... and no distractor moved more than 2 mm from its spawn |
//! | T1-3 | jaws closed with the tip within 4 mm of the spot |
//! | T2-3 | a clip: the jaws were open when the tip came within 10 mm of the named site; now closed, the tip within 4 mm of it horizontally and between the tissue surface and the vessel's centre line (the jaws straddle the vessel), crossing the vessel within 20 deg |
//! | T3-1 | gauze released, its centre over the block's top, bottom-to-top gap < 3 mm |
//! | T3-2 | gauze released, its centre within 10 mm of the target |
//!
//! Every verdict carries a short reason, so a failed episode says why.

use crate::scene::{
    BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, ObjectKind, TRAY_TOP_Z_M, VESSEL_RADIUS_M,
};
use crate::sim::grasp::line_angle_difference;
use crate::sim::observation::Observation;
use crate::sim::psm::{JAW_CLOSED_RAD, JAW_OPEN_RAD};
use crate::task::{TaskId, TaskInstance};
use nalgebra::{Point3, Vector3};
use std::f64::consts::FRAC_PI_2;

/// Lift a picked gauze needs, metres.
pub const GAUZE_LIFT_M: f64 = 0.010;
/// Lift a picked needle needs, metres.
pub const NEEDLE_LIFT_M: f64 = 0.004;
/// Tip-to-mark distance for touch and clip, metres.
pub const TOUCH_RADIUS_M: f64 = 0.004;
/// Largest angle between the jaws' closing line and the vessel's normal, radians (20 deg).
pub const CLIP_CROSSING_TOLERANCE_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;
/// Largest gap between the placed gauze's bottom and the block's top, metres.
pub const PLACE_GAP_M: f64 = 0.003;
/// Largest distance between the placed gauze and the hemostasis target, metres.
pub const HEMOSTASIS_RADIUS_M: f64 = 0.010;
/// Jaw angle that counts as closed, radians.
const JAWS_CLOSED_RAD: f64 = JAW_CLOSED_RAD + 0.02;
/// Jaw angle that counts as open when a clip reaches its site: at least half open, radians.
const JAWS_OPEN_FOR_CLIP_RAD: f64 = 0.5 * JAW_OPEN_RAD;

/// The outcome of a success check.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    pub success: bool,
    /// What held or what was missing, e.g. "gauze raised 3.1 mm < 10 mm".
    pub reason: String,
}

impl Verdict {
    fn pass(reason: impl Into<String>) -> Self {
        Verdict {
            success: true,
            reason: reason.into(),
        }
    }

    fn fail(reason: impl Into<String>) -> Self {
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
    /// Whether `observation` completes this instance's task.
    pub fn success(&self, observation: &Observation) -> Verdict {
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
        let distance = (tip - mark.position_m).norm();
        if let Some(open) = jaws_open(observation) {
            return open;
        }
        if distance > TOUCH_RADIUS_M {
            return Verdict::fail(format!(
                "tip {:.1} mm from '{}' (> {:.0} mm)",
                distance * 1e3,
                mark.name,
                TOUCH_RADIUS_M * 1e3
            ));
        }
        Verdict::pass(format!("tip {:.1} mm from '{}'", distance * 1e3, mark.name))
    }

    /// A clip: arrived with open jaws, closed around the vessel at the named site.
    fn clipped(&self, observation: &Observation) -> Verdict {
        let Some((index, mark)) = self
            .target_mark
            .and_then(|i| self.scene.marks.get(i).map(|m| (i, m)))
        else {
            return Verdict::fail("no target mark");
        };
        match observation
            .mark_approach_jaw_rad
            .get(index)
            .copied()
            .flatten()
        {
            None => {
                return Verdict::fail(format!(
                    "the tip never came within {:.0} mm of '{}'",
                    crate::sim::MARK_APPROACH_RADIUS_M * 1e3,
                    mark.name
                ));
            }
            Some(jaw) if jaw < JAWS_OPEN_FOR_CLIP_RAD => {
                return Verdict::fail(format!(
                    "the jaws were closed ({:.0} deg) when the tip reached '{}': a clip arrives open",
                    jaw.to_degrees(),
                    mark.name
                ));
            }
            Some(_) => {}
        }
        if let Some(open) = jaws_open(observation) {
            return open;
        }
        let tip = Vector3::from(observation.tip_position_m);
        let offset = tip - mark.position_m;
        let horizontal = offset.x.hypot(offset.y);
        if horizontal > TOUCH_RADIUS_M {
            return Verdict::fail(format!(
                "tip {:.1} mm beside '{}' (> {:.0} mm)",
                horizontal * 1e3,
                mark.name,
                TOUCH_RADIUS_M * 1e3
            ));
        }
        // The site mark sits on the vessel's top; the jaws straddle the vessel when the tip is
        // between the tissue below it and its centre line.
        let centre_line_z = mark.position_m.z - VESSEL_RADIUS_M;
        if !(TRAY_TOP_Z_M..=centre_line_z).contains(&tip.z) {
            return Verdict::fail(format!(
                "tip {:.1} mm {} the vessel's top: the jaws do not straddle the vessel (need {:.1}..{:.1} mm below it)",
                offset.z.abs() * 1e3,
                if offset.z >= 0.0 { "above" } else { "below" },
                VESSEL_RADIUS_M * 1e3,
                (mark.position_m.z - TRAY_TOP_Z_M) * 1e3
            ));
        }
        if let Some(line) = mark.line_direction {
            let jaw_line = observation.tip_euler_xyz_rad[2] + FRAC_PI_2;
            let off = line_angle_difference(line.y.atan2(line.x), jaw_line);
            if off > CLIP_CROSSING_TOLERANCE_RAD {
                return Verdict::fail(format!(
                    "jaws {:.0} deg off crossing the vessel",
                    off.to_degrees()
                ));
            }
        }
        Verdict::pass(format!(
            "clipped '{}': tip {:.1} mm beside it, {:.1} mm below its top",
            mark.name,
            horizontal * 1e3,
            -offset.z * 1e3
        ))
    }

    fn released_target<'a>(
        &self,
        observation: &'a Observation,
    ) -> Result<&'a crate::sim::observation::ObjectState, Verdict> {
        let target = self
            .target_object
            .ok_or_else(|| Verdict::fail("no target object"))?;
        let state = observation
            .objects
            .get(target)
            .ok_or_else(|| Verdict::fail("target object missing from the observation"))?;
        if state.bound {
            return Err(Verdict::fail(format!("'{}' still held", state.name)));
        }
        Ok(state)
    }

    fn placed_on_block(&self, observation: &Observation) -> Verdict {
        let gauze = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some(block) = self.support_object.and_then(|i| observation.objects.get(i)) else {
            return Verdict::fail("no block");
        };
        let centre = block.world_from_object.inverse()
            * Point3::from(gauze.world_from_object.translation.vector);
        if centre.x.abs() > BLOCK_HALF_EXTENTS_M[0] || centre.y.abs() > BLOCK_HALF_EXTENTS_M[1] {
            return Verdict::fail(format!(
                "gauze centre not over the block ({:.1}, {:.1}) mm",
                centre.x * 1e3,
                centre.y * 1e3
            ));
        }
        let gap = centre.z - GAUZE_HALF_EXTENTS_M[2] - BLOCK_HALF_EXTENTS_M[2];
        if !(-0.001..PLACE_GAP_M).contains(&gap) {
            return Verdict::fail(format!("gauze {:.1} mm above the block", gap * 1e3));
        }
        Verdict::pass(format!("gauze on the block, gap {:.1} mm", gap * 1e3))
    }

    fn placed_on_mark(&self, observation: &Observation) -> Verdict {
        let gauze = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
            return Verdict::fail("no target mark");
        };
        let distance = (gauze.world_from_object.translation.vector - mark.position_m).norm();
        if distance > HEMOSTASIS_RADIUS_M {
            return Verdict::fail(format!(
                "gauze {:.1} mm from the target (> {:.0} mm)",
                distance * 1e3,
                HEMOSTASIS_RADIUS_M * 1e3
            ));
        }
        Verdict::pass(format!("gauze {:.1} mm from the target", distance * 1e3))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimConfig, Simulator};
    use crate::task::TaskConfig;

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
