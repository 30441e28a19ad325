//! What a trial remembers: the events that decide a verdict whatever happens after them, kept
//! by the simulator from its start and reported with every observation.
//!
//! - the deepest the tool tip has been below a kidney's or spleen's surface;
//! - every entry of the tip into the vessel's tube (the jaw angle then, and whether it came
//!   down through the tube's top, as open jaws straddling a vessel do, or through its wall);
//! - every closing of the jaws with the tip in the vessel (where, and the jaws' crossing line
//!   at that moment);
//! - every release of every object, with the poses of all objects at that moment (a drop is
//!   judged against its support where the support was then);
//! - every grasp (whether an object was ever held follows).
//!
//! The simulator records at every control step's end (and after a teleport), so an event is
//! seen at 5 Hz; what happened between two records is judged from the segment between them
//! where it matters (the entry into the vessel).

use crate::scene::{OrganKind, SceneSpec, organ};
use nalgebra::{Isometry3, Vector3};

/// The tip's entry into the vessel's tube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesselEntry {
    pub step_index: u64,
    /// The first recorded tip position inside the tube, world.
    pub tip_m: [f64; 3],
    /// Jaw angle when the tip entered, radians.
    pub jaw_angle_rad: f64,
    /// Yaw of the jaws' line when the tip entered (the tip's yaw + 90 deg), radians.
    pub jaw_line_rad: f64,
    /// Whether the tip came in through the tube's top quarter (its path from the last position
    /// outside crossed the tube's wall within 45 deg of straight up), as open jaws straddling
    /// a vessel do; otherwise it went through the vessel's wall.
    pub from_above: bool,
}

/// The jaws closing with the tip in the vessel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesselClosure {
    pub step_index: u64,
    /// Tip position when the jaws closed, world.
    pub tip_m: [f64; 3],
    /// Yaw of the jaws' line when they closed (the tip's yaw + 90 deg), radians.
    pub jaw_line_rad: f64,
    /// How the tip entered the vessel before the jaws closed.
    pub entry: VesselEntry,
}

/// One release of a held object.
#[derive(Clone, Debug, PartialEq)]
pub struct Release {
    pub step_index: u64,
    /// The released object's grasp frame then.
    pub world_from_object: Isometry3<f64>,
    /// Every object's grasp frame then, in scene order (its support's among them).
    pub world_from_objects: Vec<Isometry3<f64>>,
}

/// What a [`ContactEvent`] was.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum ContactKind {
    Grasped,
    Released,
    EnteredVesselFromAbove,
    EnteredVesselThroughWall,
    ClosedInVessel,
}

impl ContactKind {
    /// Every kind.
    pub const ALL: [ContactKind; 5] = [
        ContactKind::Grasped,
        ContactKind::Released,
        ContactKind::EnteredVesselFromAbove,
        ContactKind::EnteredVesselThroughWall,
        ContactKind::ClosedInVessel,
    ];

    /// Its name in results (snake case).
    pub fn name(self) -> &'static str {
        match self {
            ContactKind::Grasped => "grasped",
            ContactKind::Released => "released",
            ContactKind::EnteredVesselFromAbove => "entered_vessel_from_above",
            ContactKind::EnteredVesselThroughWall => "entered_vessel_through_wall",
            ContactKind::ClosedInVessel => "closed_in_vessel",
        }
    }
}

/// One contact event of a trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactEvent {
    /// The control step it happened at (0: before the first).
    pub step_index: u64,
    pub kind: ContactKind,
    /// The object grasped or released (scene index).
    pub object: Option<usize>,
}

/// A trial's memory (see the module's overview).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrialHistory {
    /// The deepest the tool tip has been below a kidney's or spleen's surface, metres (0: never
    /// inside one).
    pub peak_penetration_m: f64,
    /// Every entry of the tip into the vessel, in order.
    pub vessel_entries: Vec<VesselEntry>,
    /// Every closing of the jaws with the tip in the vessel, in order.
    pub vessel_closures: Vec<VesselClosure>,
    /// Every grasp: (control step, object index), in order.
    pub grasps: Vec<(u64, usize)>,
    /// Per object: its releases, in order.
    pub releases: Vec<Vec<Release>>,
    /// The entry the tip is in now (None: outside the vessel).
    current_entry: Option<VesselEntry>,
    /// Tip position and jaws closed at the last record.
    last_tip_m: Option<Vector3<f64>>,
    jaws_were_closed: bool,
}

/// What the simulator knows at a record.
pub(crate) struct Moment<'a> {
    pub step_index: u64,
    pub tip_m: Vector3<f64>,
    pub tip_yaw_rad: f64,
    pub jaw_angle_rad: f64,
    /// The jaws count as closed.
    pub jaws_closed: bool,
    pub scene: &'a SceneSpec,
}

impl TrialHistory {
    /// An empty history for a scene of `objects` movable objects.
    pub fn new(objects: usize) -> Self {
        TrialHistory {
            releases: vec![Vec::new(); objects],
            ..TrialHistory::default()
        }
    }

    /// Records the tip's penetration and its passage through the vessel at `moment`.
    pub(crate) fn record(&mut self, moment: &Moment) {
        let tip = moment.tip_m;
        let organs = || moment.scene.organs.iter();
        let depth_m = organs()
            .filter(|o| o.kind != OrganKind::Vessel)
            .map(|o| -organ::radial_gap_m(o, &tip))
            .fold(0.0, f64::max);
        self.peak_penetration_m = self.peak_penetration_m.max(depth_m);
        let vessel = organs().find(|o| o.kind == OrganKind::Vessel);
        let inside = vessel.is_some_and(|v| organ::vessel_section(v, &tip).inside())
            || (moment.scene.marks.iter())
                .any(|m| m.clip_offset(&tip).is_some_and(|o| o.in_band()));
        match (inside, self.current_entry) {
            (false, _) => self.current_entry = None,
            (true, None) => {
                let from_above = match (vessel, self.last_tip_m) {
                    (Some(v), Some(last)) => entered_from_above(v, &last, &tip),
                    _ => false,
                };
                let entry = VesselEntry {
                    step_index: moment.step_index,
                    tip_m: tip.into(),
                    jaw_angle_rad: moment.jaw_angle_rad,
                    jaw_line_rad: moment.tip_yaw_rad + std::f64::consts::FRAC_PI_2,
                    from_above,
                };
                self.vessel_entries.push(entry);
                self.current_entry = Some(entry);
            }
            (true, Some(_)) => {}
        }
        if let Some(entry) = self.current_entry
            && moment.jaws_closed
            && !self.jaws_were_closed
        {
            self.vessel_closures.push(VesselClosure {
                step_index: moment.step_index,
                tip_m: tip.into(),
                jaw_line_rad: moment.tip_yaw_rad + std::f64::consts::FRAC_PI_2,
                entry,
            });
        }
        self.jaws_were_closed = moment.jaws_closed;
        self.last_tip_m = Some(tip);
    }

    /// Records that object `index` was bound at `step_index`.
    pub(crate) fn bound(&mut self, index: usize, step_index: u64) {
        self.grasps.push((step_index, index));
    }

    /// Whether object `index` was held at any time.
    pub fn ever_bound(&self, index: usize) -> bool {
        self.grasps.iter().any(|&(_, object)| object == index)
    }

    /// The trial's contact events in time order: grasps and releases (with the object's
    /// index), the tip's entries into the vessel and the jaws' closings there.
    pub fn events(&self) -> Vec<ContactEvent> {
        let mut events: Vec<ContactEvent> = (self.grasps.iter())
            .map(|&(step_index, object)| ContactEvent {
                step_index,
                kind: ContactKind::Grasped,
                object: Some(object),
            })
            .collect();
        for (object, releases) in self.releases.iter().enumerate() {
            events.extend(releases.iter().map(|r| ContactEvent {
                step_index: r.step_index,
                kind: ContactKind::Released,
                object: Some(object),
            }));
        }
        events.extend(self.vessel_entries.iter().map(|e| ContactEvent {
            step_index: e.step_index,
            kind: if e.from_above {
                ContactKind::EnteredVesselFromAbove
            } else {
                ContactKind::EnteredVesselThroughWall
            },
            object: None,
        }));
        events.extend(self.vessel_closures.iter().map(|c| ContactEvent {
            step_index: c.step_index,
            kind: ContactKind::ClosedInVessel,
            object: None,
        }));
        events.sort_by_key(|e| (e.step_index, e.kind));
        events
    }

    /// Records the release of object `index` at `world_from_objects[index]`.
    pub(crate) fn released(
        &mut self,
        index: usize,
        step_index: u64,
        world_from_objects: Vec<Isometry3<f64>>,
    ) {
        let (Some(releases), Some(pose)) = (
            self.releases.get_mut(index),
            world_from_objects.get(index).copied(),
        ) else {
            return;
        };
        releases.push(Release {
            step_index,
            world_from_object: pose,
            world_from_objects,
        });
    }
}

/// Whether the tip, moving from `outside_m` (outside the vessel's tube) to `inside_m` (inside
/// it), crossed the tube's wall in its top quarter: within 45 deg of straight up in the
/// cross-section.
fn entered_from_above(
    vessel: &crate::scene::OrganSpec,
    outside_m: &Vector3<f64>,
    inside_m: &Vector3<f64>,
) -> bool {
    let a = organ::vessel_section(vessel, outside_m);
    let b = organ::vessel_section(vessel, inside_m);
    // Where the segment a -> b meets the circle of the tube's radius, in the cross-section.
    let (ax, ay) = (a.across_m, a.above_axis_m);
    let (dx, dy) = (b.across_m - ax, b.above_axis_m - ay);
    let (qa, qb, qc) = (
        dx * dx + dy * dy,
        2.0 * (ax * dx + ay * dy),
        ax * ax + ay * ay - a.radius_m * a.radius_m,
    );
    let discriminant = qb * qb - 4.0 * qa * qc;
    if qa <= 0.0 || discriminant < 0.0 {
        // No crossing in the section: the tip was already inside or moved along the vessel.
        return b.above_axis_m >= b.across_m.abs();
    }
    let t = ((-qb - discriminant.sqrt()) / (2.0 * qa)).clamp(0.0, 1.0);
    let (x, y) = (ax + t * dx, ay + t * dy);
    y >= x.abs()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{OrganSpec, VESSEL_RADIUS_M};

    fn vessel() -> OrganSpec {
        OrganSpec {
            kind: OrganKind::Vessel,
            world_from_organ: Isometry3::translation(0.55, 0.0, 0.68),
            semi_axes_m: [0.0, 0.07, VESSEL_RADIUS_M],
            shape_seed: 1,
        }
    }

    /// The vessel runs along y (no wiggle): x is across it.
    #[test]
    fn an_entry_is_from_above_only_through_the_top_quarter_of_the_wall() {
        let v = vessel();
        let at = |x: f64, z: f64| Vector3::new(0.55 + x, 0.0, 0.68 + z);
        // Straight down; down and 1 mm sideways.
        assert!(entered_from_above(&v, &at(0.0, 0.005), &at(0.0, -0.001)));
        assert!(entered_from_above(&v, &at(0.001, 0.006), &at(0.0, 0.0)));
        // Sideways through the wall at the axis' height; up from below; diagonally through the
        // upper side wall (60 deg from the top).
        assert!(!entered_from_above(&v, &at(0.004, 0.0), &at(0.0, 0.0)));
        assert!(!entered_from_above(&v, &at(0.0, -0.004), &at(0.0, 0.0)));
        assert!(!entered_from_above(
            &v,
            &at(0.006, 0.0035),
            &at(0.0015, 0.0)
        ));
    }

    #[test]
    fn the_section_measures_across_and_above_the_centre_line() {
        let section = organ::vessel_section(&vessel(), &Vector3::new(0.552, 0.01, 0.679));
        assert!((section.across_m.abs() - 0.002).abs() < 1e-9, "{section:?}");
        assert!((section.above_axis_m + 0.001).abs() < 1e-9);
        assert!((section.along_m - 0.08).abs() < 1e-9);
        assert!(section.inside(), "2.2 mm from the axis, inside 2.5 mm");
    }
}
