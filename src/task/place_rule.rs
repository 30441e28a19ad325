//! T3-1's and T3-2's placement, judged from the trial's releases (`sim::history`), each at the
//! moment it happened:
//!
//! - every release of the gauze is a placement or a drop: its underside at most
//!   [`PLACE_RELEASE_HEIGHT_M`] above what is under it (the block where the block was then, the
//!   spleen, or the tray) when the jaws let go. A drop ends the trial, and picking the gauze up
//!   again does not forgive it;
//! - the support stays a support: the block held by the jaws ends the trial, and the block
//!   moved more than 2 mm since the gauze was let go on it fails the placement;
//! - at the end, the gauze released last is settled and resting on its support: for T3-1 its
//!   centre over the block's top with a gap under 3 mm; for T3-2 on the spleen, the spot wholly
//!   under its footprint when it was let go, and still under it (within
//!   [`PLACE_SLIDE_M`] of its edge) after the tissue let it slide.

use crate::scene::{BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, TRAY_TOP_Z_M, organ};
use crate::sim::MOVED_THRESHOLD_M;
use crate::sim::history::Release;
use crate::sim::observation::{ObjectState, Observation};
use crate::task::id::TaskId;
use crate::task::spawn::TaskInstance;
use crate::task::success::Verdict;
use nalgebra::{Isometry3, Point3};

/// Highest a gauze may be let go above what is under it and count as placed, metres (measured
/// from its underside).
pub const PLACE_RELEASE_HEIGHT_M: f64 = 0.005;
/// Largest gap between the placed gauze's bottom and its support, metres.
pub const PLACE_GAP_M: f64 = 0.003;
/// A placed object moving slower than this has settled, metres per second: a gauze on the
/// spleen's curve jitters in contact at up to 15 mm/s for seconds before the engine puts it to
/// sleep; one let go in the air falls faster than this within 0.02 s.
pub const SETTLED_SPEED_M_PER_S: f64 = 0.02;
/// How far the hemostasis spot's edge may end up beyond the gauze's after the gauze, let go
/// with the spot wholly under it, slid on the spleen's curved flank, metres.
pub const PLACE_SLIDE_M: f64 = 0.003;

/// The gauze's underside (the centre of its bottom face) at `pose`.
fn underside(pose: &Isometry3<f64>) -> Point3<f64> {
    pose * Point3::new(0.0, 0.0, -GAUZE_HALF_EXTENTS_M[2])
}

impl TaskInstance {
    fn is_placement(&self) -> bool {
        matches!(self.task, TaskId::PickAndPlace | TaskId::Hemostasis)
    }

    /// How high above what was under it the gauze was let go in `release`, metres: the least
    /// of its underside's height over the tray, over the block's top (where the block was
    /// then) and over the spleen's surface.
    fn release_height_m(&self, release: &Release) -> f64 {
        let bottom = underside(&release.world_from_object);
        let over_tray = bottom.z - TRAY_TOP_Z_M;
        let over_block = (self.support_object)
            .and_then(|i| release.world_from_objects.get(i))
            .map_or(f64::INFINITY, |block| {
                (block.inverse() * bottom).z - BLOCK_HALF_EXTENTS_M[2]
            });
        let over_organ = (self.target_mark)
            .and_then(|i| self.scene.marks.get(i))
            .and_then(|mark| self.organ_under(&mark.position_m))
            .map_or(f64::INFINITY, |o| organ::radial_gap_m(o, &bottom.coords));
        over_tray.min(over_block).min(over_organ)
    }

    /// The placement failure the trial's history holds, if any: the gauze dropped from height
    /// at any release, or the block (the support) held.
    pub(super) fn placement_failure(&self, observation: &Observation) -> Option<Verdict> {
        if !self.is_placement() {
            return None;
        }
        if let Some(block) = self.support_object.and_then(|i| observation.objects.get(i))
            && block.ever_bound
        {
            return Some(Verdict::fail(format!(
                "the jaws held '{}', the gauze's support",
                block.name
            )));
        }
        let releases = self
            .target_object
            .and_then(|i| observation.history.releases.get(i))?;
        releases.iter().find_map(|release| {
            let height = self.release_height_m(release);
            (height > PLACE_RELEASE_HEIGHT_M).then(|| {
                Verdict::fail(format!(
                    "gauze dropped from {:.1} mm above its support at step {} (placing is within {:.0} mm)",
                    height * 1e3,
                    release.step_index,
                    PLACE_RELEASE_HEIGHT_M * 1e3
                ))
            })
        })
    }

    /// The target object, let go by the jaws and at rest, with its last release.
    fn released_target<'a>(
        &self,
        observation: &'a Observation,
    ) -> Result<(&'a ObjectState, &'a Release), Verdict> {
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
        let Some(release) = observation
            .history
            .releases
            .get(target)
            .and_then(|r| r.last())
        else {
            return Err(Verdict::fail(format!("'{}' never placed", state.name)));
        };
        if !state.at_rest && state.speed_m_per_s > SETTLED_SPEED_M_PER_S {
            return Err(Verdict::fail(format!(
                "'{}' still moving ({:.0} mm/s)",
                state.name,
                state.speed_m_per_s * 1e3
            )));
        }
        Ok((state, release))
    }

    pub(super) fn placed_on_block(&self, observation: &Observation) -> Verdict {
        let (gauze, release) = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some((index, block)) = self
            .support_object
            .and_then(|i| observation.objects.get(i).map(|b| (i, b)))
        else {
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
        if let Some(then) = release.world_from_objects.get(index) {
            let moved =
                (block.world_from_object.translation.vector - then.translation.vector).norm();
            if moved > MOVED_THRESHOLD_M {
                return Verdict::fail(format!(
                    "the block moved {:.1} mm after the gauze was let go on it",
                    moved * 1e3
                ));
            }
        }
        Verdict::pass(format!(
            "gauze placed on the block from {:.1} mm, gap {:.1} mm",
            self.release_height_m(release) * 1e3,
            gap * 1e3
        ))
    }

    pub(super) fn placed_on_mark(&self, observation: &Observation) -> Verdict {
        let (gauze, release) = match self.released_target(observation) {
            Ok(state) => state,
            Err(verdict) => return verdict,
        };
        let Some(mark) = self.target_mark.and_then(|i| self.scene.marks.get(i)) else {
            return Verdict::fail("no target mark");
        };
        // How far the spot's edge lies beyond the gauze's footprint (<= 0: wholly under it).
        let uncovered_m = |pose: &Isometry3<f64>| {
            let spot = pose.inverse() * Point3::from(mark.position_m);
            let [hx, hy, _] = GAUZE_HALF_EXTENTS_M;
            (spot.x.abs() + mark.radius_m - hx).max(spot.y.abs() + mark.radius_m - hy)
        };
        let at_release = uncovered_m(&release.world_from_object);
        if at_release > 0.0 {
            return Verdict::fail(format!(
                "'{}' not under the gauze when it was let go (its edge {:.1} mm beyond the gauze's)",
                mark.name,
                at_release * 1e3
            ));
        }
        let now = uncovered_m(&gauze.world_from_object);
        if now > PLACE_SLIDE_M {
            return Verdict::fail(format!(
                "the gauze slid off '{}' (its edge {:.1} mm beyond the gauze's; a slide may leave {:.0} mm)",
                mark.name,
                now * 1e3,
                PLACE_SLIDE_M * 1e3
            ));
        }
        // Resting on the organ the spot is on: its underside on the surface there.
        let Some(organ) = self.organ_under(&mark.position_m) else {
            return Verdict::fail("no organ under the target");
        };
        let resting = organ::radial_gap_m(organ, &underside(&gauze.world_from_object).coords);
        if resting.abs() > PLACE_GAP_M {
            return Verdict::fail(format!(
                "gauze {:.1} mm {} the {}'s surface, not resting on it",
                resting.abs() * 1e3,
                if resting > 0.0 { "above" } else { "inside" },
                organ.kind.name()
            ));
        }
        Verdict::pass(format!(
            "'{}' covered, gauze placed on the {} from {:.1} mm",
            mark.name,
            organ.kind.name(),
            self.release_height_m(release) * 1e3
        ))
    }
}
