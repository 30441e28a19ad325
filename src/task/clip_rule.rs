//! T2-3's clip, judged from the trial's history of the vessel (`sim::history`), each event at
//! the moment it happened:
//!
//! - the tip must enter the vessel with the jaws at least half open, across it (within 20 deg)
//!   and through the tube's top quarter, as open jaws straddling it come down; closed jaws pushed
//!   into it, open jaws driven through its wall, or open jaws coming down along it (a blade on
//!   the vessel) end the trial there;
//! - the jaws' closing with the tip in the vessel is the clip. It counts only with the tip in
//!   the band around the named site (1.5 mm of the axis across it, 4 mm along it, between the
//!   tissue and the centre line), the jaws having entered the vessel within that band's reach
//!   along it (not slid along inside from further away), and crossing the vessel within 20 deg
//!   *as they closed*. A closing anywhere else in the vessel ends the trial: a clip cannot be
//!   taken back.
//!
//! Once applied, a clip stays: what the jaws do afterwards does not undo the success.

use crate::scene::{CLIP_BAND_ACROSS_M, CLIP_BAND_ALONG_M, MarkSpec};
use crate::sim::grasp::line_angle_difference;
use crate::sim::history::VesselClosure;
use crate::sim::observation::Observation;
use crate::sim::psm::JAW_OPEN_RAD;
use crate::task::spawn::TaskInstance;
use crate::task::success::Verdict;
use nalgebra::Vector3;

/// Largest angle between the jaws' closing line and the vessel's normal when they close,
/// radians (20 deg).
pub const CLIP_CROSSING_TOLERANCE_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;
/// Jaw angle that counts as open when the jaws enter the vessel: at least half open, radians.
pub const JAWS_OPEN_FOR_CLIP_RAD: f64 = 0.5 * JAW_OPEN_RAD;

impl TaskInstance {
    /// The first decisive event of the vessel's history, in time order: an entry with the
    /// jaws closed or through the wall (a failure), or the first closing (a clip at the named
    /// site, or a failure). None while nothing has decided.
    pub(super) fn vessel_decision(&self, observation: &Observation) -> Option<Verdict> {
        let history = &observation.history;
        let entry_failure = history.vessel_entries.iter().find_map(|entry| {
            let why = if entry.jaw_angle_rad < JAWS_OPEN_FOR_CLIP_RAD {
                format!(
                    "the jaws were closed ({:.0} deg) when the tip went into the vessel (step {}): a clip closes around it",
                    entry.jaw_angle_rad.to_degrees(),
                    entry.step_index
                )
            } else if !entry.from_above {
                format!(
                    "the open jaws went through the vessel's wall (step {}): they straddle it from above",
                    entry.step_index
                )
            } else if let Some(off) = self.off_crossing_rad(&entry.tip_m, entry.jaw_line_rad)
                && off > CLIP_CROSSING_TOLERANCE_RAD
            {
                format!(
                    "the open jaws came down on the vessel {:.0} deg off crossing it (step {}): a blade lands on it",
                    off.to_degrees(),
                    entry.step_index
                )
            } else {
                return None;
            };
            Some((entry.step_index, Verdict::fail(why)))
        });
        let closure = (history.vessel_closures.first())
            .map(|closure| (closure.step_index, self.judge_closure(closure)));
        match (entry_failure, closure) {
            (Some((at, failure)), Some((closed_at, _))) if at <= closed_at => Some(failure),
            (_, Some((_, verdict))) => Some(verdict),
            (entry, None) => entry.map(|(_, failure)| failure),
        }
    }

    /// Whether the jaws closing as `closure` records applied a clip at the named site.
    fn judge_closure(&self, closure: &VesselClosure) -> Verdict {
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
            return Verdict::fail("no target mark");
        };
        let tip = Vector3::from(closure.tip_m);
        let Some(offset) = mark.clip_offset(&tip) else {
            return Verdict::fail(format!("'{}' is not on a vessel", mark.name));
        };
        let step = closure.step_index;
        if !offset.in_band() {
            if let Some(other) =
                self.scene.marks.iter().find(|m| {
                    m.name != mark.name && m.clip_offset(&tip).is_some_and(|o| o.in_band())
                })
            {
                return Verdict::fail(format!(
                    "clipped '{}', not '{}' (step {step})",
                    other.name, mark.name
                ));
            }
            return Verdict::fail(format!(
                "the jaws closed in the vessel {:.1} mm along it and {:.1} mm across its axis from '{}', {:.1} mm above its centre line (step {step}): a clip closes within {:.1} mm of the axis, {:.0} mm of the site, below the centre line",
                offset.along_m * 1e3,
                offset.across_m * 1e3,
                mark.name,
                offset.above_centre_line_m * 1e3,
                CLIP_BAND_ACROSS_M * 1e3,
                CLIP_BAND_ALONG_M * 1e3
            ));
        }
        let entered = entry_along_m(mark, &closure.entry.tip_m);
        if entered > CLIP_BAND_ALONG_M {
            return Verdict::fail(format!(
                "the jaws went into the vessel {:.1} mm along it from '{}' and slid along inside it (step {}): a clip comes down on the site",
                entered * 1e3,
                mark.name,
                closure.entry.step_index
            ));
        }
        if let Some(off) = self.off_crossing_rad(&closure.tip_m, closure.jaw_line_rad)
            && off > CLIP_CROSSING_TOLERANCE_RAD
        {
            return Verdict::fail(format!(
                "the jaws closed {:.0} deg off crossing the vessel (step {step}; a clip crosses it within {:.0} deg)",
                off.to_degrees(),
                CLIP_CROSSING_TOLERANCE_RAD.to_degrees()
            ));
        }
        Verdict::pass(format!(
            "clipped '{}' at step {step}: tip {:.1} mm from the axis, {:.1} mm along it, {:.1} mm below the centre line",
            mark.name,
            offset.across_m * 1e3,
            offset.along_m * 1e3,
            -offset.above_centre_line_m * 1e3
        ))
    }

    /// How far jaws whose line has yaw `jaw_line_rad` are from crossing the vessel at `tip_m`
    /// (the direction of the clip site nearest along it), radians; None without a vessel.
    /// Evaluation reports it for the first closure as the clip's angle error.
    pub fn off_crossing_rad(&self, tip_m: &[f64; 3], jaw_line_rad: f64) -> Option<f64> {
        let tip = Vector3::from(*tip_m);
        let nearest = (self.scene.marks.iter())
            .filter_map(|m| Some((m.clip_offset(&tip)?.along_m, m.line_direction?)))
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        let line = nearest.1;
        Some(line_angle_difference(line.y.atan2(line.x), jaw_line_rad))
    }

    /// A clip at the named site: one applied (see the module's overview), or why not.
    pub(super) fn clipped(&self, observation: &Observation) -> Verdict {
        if let Some(decision) = self.vessel_decision(observation) {
            return decision;
        }
        // No clip yet: say how far the tip is from applying one.
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
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
        Verdict::fail("the jaws have not closed on the vessel")
    }
}

/// How far along the vessel from `mark` the tip entered it, metres.
fn entry_along_m(mark: &MarkSpec, entry_tip_m: &[f64; 3]) -> f64 {
    mark.clip_offset(&Vector3::from(*entry_tip_m))
        .map_or(f64::INFINITY, |o| o.along_m)
}
