//! Success predicates: whether an observation completes the task of a [`TaskInstance`]. Each
//! judges the physical event (rule set [`RULE_SET`]; docs/FIDELITY.md gives every rule with a
//! motion that passes and one that fails):
//!
//! | task | success |
//! |---|---|
//! | T1-1, T2-1 | the named gauze bound (the jaws closed on its top face: see `sim::grasp`) and raised >= 10 mm |
//! | T1-2, T2-2 | the named needle bound (the jaws closed on its wire, across it), raised >= 4 mm, not touching the tray |
//! | T2-1, T2-2 | ... and no distractor ever grasped (a terminal failure: the trial ends there) or moved more than 2 mm |
//! | T1-3 | jaws closed, the tip on the organ's surface (within 1 mm of it, either side) within 4 mm of the spot |
//! | T2-3 | a clip: the jaws were open when the tip entered the band around the named site (within 1.5 mm of the vessel's axis across it, 4 mm along it, between the tissue and the vessel's centre line), closed while inside it, crossing the vessel within 20 deg |
//! | T3-1 | the gauze placed: let go within 5 mm above the block, at rest, its centre over the block's top, bottom-to-top gap < 3 mm |
//! | T3-2 | the gauze placed: let go within 5 mm above the spleen, at rest on it (underside within 3 mm of its surface), the target spot wholly under its footprint |
//!
//! Every verdict carries a short reason, so a failed episode says why.

use crate::scene::{
    BLOCK_HALF_EXTENTS_M, CLIP_BAND_ACROSS_M, CLIP_BAND_ALONG_M, GAUZE_HALF_EXTENTS_M, ObjectKind,
    OrganKind, OrganSpec, organ,
};
use crate::sim::grasp::line_angle_difference;
use crate::sim::observation::Observation;
use crate::sim::psm::{JAW_CLOSED_RAD, JAW_OPEN_RAD};
use crate::task::id::TaskId;
use crate::task::spawn::TaskInstance;
use nalgebra::{Isometry3, Point3, Vector3};
use std::f64::consts::FRAC_PI_2;

/// The name and version of these rules, recorded with every dataset and evaluation: a dataset
/// judged by other rules is not re-judged by these.
pub const RULE_SET: &str = "surgvla-physical-v1";

/// Lift a picked gauze needs, metres.
pub const GAUZE_LIFT_M: f64 = 0.010;
/// Lift a picked needle needs, metres.
pub const NEEDLE_LIFT_M: f64 = 0.004;
/// Tip-to-mark distance for touch and clip, metres.
pub const TOUCH_RADIUS_M: f64 = 0.004;
/// Largest distance between the touching tip and the organ's surface, either side, metres:
/// on the tissue, neither hovering over it nor pushed into it.
pub const TOUCH_SURFACE_GAP_M: f64 = 0.001;
/// Largest angle between the jaws' closing line and the vessel's normal, radians (20 deg).
pub const CLIP_CROSSING_TOLERANCE_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;
/// Largest gap between the placed gauze's bottom and the block's top, metres.
pub const PLACE_GAP_M: f64 = 0.003;
/// A placed object moving slower than this has settled, metres per second: a gauze on the
/// spleen's curve jitters in contact at up to 15 mm/s for seconds before the engine puts it to
/// sleep; one let go in the air falls faster than this within 0.02 s.
pub const SETTLED_SPEED_M_PER_S: f64 = 0.02;
/// Highest a gauze may be let go above its support and count as placed, metres (measured from
/// its underside).
pub const PLACE_RELEASE_HEIGHT_M: f64 = 0.005;
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
    /// The solid organ a mark lies on: the one whose surface passes nearest it.
    fn organ_under(&self, mark_m: &Vector3<f64>) -> Option<&OrganSpec> {
        let at_mark = |o: &OrganSpec| organ::radial_gap_m(o, mark_m).abs();
        self.scene
            .organs
            .iter()
            .filter(|o| o.kind != OrganKind::Vessel)
            .min_by(|a, b| at_mark(a).total_cmp(&at_mark(b)))
    }

    /// A failure that ends a trial (or an expert attempt) the moment it happens, whatever
    /// follows: a distractor grasped (T2-1, T2-2).
    pub fn terminal_failure(&self, observation: &Observation) -> Option<Verdict> {
        observation
            .objects
            .iter()
            .zip(&self.scene.objects)
            .find(|(state, spec)| spec.distractor && state.ever_bound)
            .map(|(_, spec)| Verdict::fail(format!("grasped the distractor '{}'", spec.name)))
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
        let Some(gap) = self
            .organ_under(&mark.position_m)
            .map(|o| organ::radial_gap_m(o, &tip))
        else {
            return Verdict::fail("no tissue to touch");
        };
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

    /// A clip: the jaws entered the band around the vessel at the named site open, closed
    /// there, and cross the vessel.
    fn clipped(&self, observation: &Observation) -> Verdict {
        let Some((index, mark)) = self
            .target_mark
            .and_then(|i| self.scene.marks.get(i).map(|m| (i, m)))
        else {
            return Verdict::fail("no target mark");
        };
        let tip = Vector3::from(observation.tip_position_m);
        let Some(offset) = mark.clip_offset(&tip) else {
            return Verdict::fail(format!("'{}' is not on a vessel", mark.name));
        };
        if offset.across_m > CLIP_BAND_ACROSS_M || offset.along_m > CLIP_BAND_ALONG_M {
            return Verdict::fail(format!(
                "tip {:.1} mm from the vessel's axis and {:.1} mm along it from '{}' (a clip closes within {:.1} mm of the axis, {:.0} mm of the site)",
                offset.across_m * 1e3,
                offset.along_m * 1e3,
                mark.name,
                CLIP_BAND_ACROSS_M * 1e3,
                CLIP_BAND_ALONG_M * 1e3
            ));
        }
        if !offset.in_band() {
            return Verdict::fail(format!(
                "tip {:.1} mm above the vessel's centre line, {:.1} mm above the tissue: the jaws do not straddle the vessel",
                offset.above_centre_line_m * 1e3,
                offset.above_tissue_m * 1e3
            ));
        }
        match observation.clip_entry_jaw_rad.get(index).copied().flatten() {
            None => return Verdict::fail("the tip is not in the clip band"),
            Some(jaw) if jaw < JAWS_OPEN_FOR_CLIP_RAD => {
                return Verdict::fail(format!(
                    "the jaws were closed ({:.0} deg) when the tip reached the vessel at '{}': a clip closes around it",
                    jaw.to_degrees(),
                    mark.name
                ));
            }
            Some(_) => {}
        }
        if let Some(open) = jaws_open(observation) {
            return open;
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
            "clipped '{}': tip {:.1} mm from the axis, {:.1} mm along it, {:.1} mm below the centre line",
            mark.name,
            offset.across_m * 1e3,
            offset.along_m * 1e3,
            -offset.above_centre_line_m * 1e3
        ))
    }

    /// The target object, let go by the jaws and at rest, with its pose when released.
    fn released_target<'a>(
        &self,
        observation: &'a Observation,
    ) -> Result<(&'a crate::sim::observation::ObjectState, Isometry3<f64>), Verdict> {
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
        let Some(released_at) = state.released_at else {
            return Err(Verdict::fail(format!("'{}' never placed", state.name)));
        };
        if !state.at_rest && state.speed_m_per_s > SETTLED_SPEED_M_PER_S {
            return Err(Verdict::fail(format!(
                "'{}' still moving ({:.0} mm/s)",
                state.name,
                state.speed_m_per_s * 1e3
            )));
        }
        Ok((state, released_at))
    }

    /// A released object dropped from higher than [`PLACE_RELEASE_HEIGHT_M`] was thrown, not
    /// placed.
    fn dropped(&self, height_m: f64) -> Option<Verdict> {
        (height_m > PLACE_RELEASE_HEIGHT_M).then(|| {
            Verdict::fail(format!(
                "gauze released {:.1} mm above its support (placing is within {:.0} mm)",
                height_m * 1e3,
                PLACE_RELEASE_HEIGHT_M * 1e3
            ))
        })
    }

    fn placed_on_block(&self, observation: &Observation) -> Verdict {
        let (gauze, released_at) = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some(block) = self.support_object.and_then(|i| observation.objects.get(i)) else {
            return Verdict::fail("no block");
        };
        let block_from_world = block.world_from_object.inverse();
        let centre = block_from_world * Point3::from(gauze.world_from_object.translation.vector);
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
        let released = block_from_world * Point3::from(released_at.translation.vector);
        let height = released.z - GAUZE_HALF_EXTENTS_M[2] - BLOCK_HALF_EXTENTS_M[2];
        if let Some(dropped) = self.dropped(height) {
            return dropped;
        }
        Verdict::pass(format!(
            "gauze placed on the block from {:.1} mm, gap {:.1} mm",
            height * 1e3,
            gap * 1e3
        ))
    }

    fn placed_on_mark(&self, observation: &Observation) -> Verdict {
        let (gauze, released_at) = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
            return Verdict::fail("no target mark");
        };
        // The spot under the footprint, all of it: its centre within the footprint shrunk by
        // its radius.
        let spot = gauze.world_from_object.inverse() * Point3::from(mark.position_m);
        let [hx, hy, hz] = GAUZE_HALF_EXTENTS_M;
        let uncovered_x = spot.x.abs() + mark.radius_m - hx;
        let uncovered_y = spot.y.abs() + mark.radius_m - hy;
        if uncovered_x > 0.0 || uncovered_y > 0.0 {
            return Verdict::fail(format!(
                "'{}' not under the gauze (its edge {:.1} mm beyond the gauze's)",
                mark.name,
                uncovered_x.max(uncovered_y) * 1e3
            ));
        }
        // Resting on the organ the spot is on: its underside on the surface there.
        let Some(organ) = self.organ_under(&mark.position_m) else {
            return Verdict::fail("no organ under the target");
        };
        let underside = |pose: &Isometry3<f64>| (pose * Point3::new(0.0, 0.0, -hz)).coords;
        let resting = organ::radial_gap_m(organ, &underside(&gauze.world_from_object));
        if resting.abs() > PLACE_GAP_M {
            return Verdict::fail(format!(
                "gauze {:.1} mm {} the {}'s surface, not resting on it",
                resting.abs() * 1e3,
                if resting > 0.0 { "above" } else { "inside" },
                organ.kind.name()
            ));
        }
        let height = organ::radial_gap_m(organ, &underside(&released_at));
        if let Some(dropped) = self.dropped(height) {
            return dropped;
        }
        Verdict::pass(format!(
            "'{}' covered, gauze placed on the {} from {:.1} mm",
            mark.name,
            organ.kind.name(),
            height * 1e3
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
