//! The eight SurgVLA-Bench tasks: identifiers, names, levels, step limits, canonical
//! instructions, and seeded scene construction with the reference spawn ranges.
//!
//! Success predicates and expert plans build on these (see `scripted_policies/`). Spawn
//! positions come from a per-task random stream of the episode seed, so a scene is a pure
//! function of (task, seed).

use crate::assets::organ;
use crate::rng::SplitMix64;
use crate::scene::{
    MarkColour, MarkSpec, ObjectKind, ObjectSpec, OrganKind, OrganSpec, SceneSpec, TRAY_TOP_Z_M,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::fmt;
use std::str::FromStr;

/// Reference workspace floor z0, metres (organ heights are given relative to it).
pub const Z0_M: f64 = 0.6852;

/// One of the eight benchmark tasks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TaskId {
    GauzePick,
    NeedlePick,
    Electrocoagulation,
    GauzePickDistractors,
    NeedlePickDistractors,
    VesselClipping,
    PickAndPlace,
    Hemostasis,
}

/// An unknown task name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown task '{given}'; expected one of: {}", TaskId::ALL.iter().map(|t| format!("{} ({})", t.name(), t.code())).collect::<Vec<_>>().join(", "))]
pub struct UnknownTask {
    pub given: String,
}

impl TaskId {
    /// All tasks in benchmark order.
    pub const ALL: [TaskId; 8] = [
        TaskId::GauzePick,
        TaskId::NeedlePick,
        TaskId::Electrocoagulation,
        TaskId::GauzePickDistractors,
        TaskId::NeedlePickDistractors,
        TaskId::VesselClipping,
        TaskId::PickAndPlace,
        TaskId::Hemostasis,
    ];

    /// The benchmark id, e.g. "T1-1".
    pub fn code(self) -> &'static str {
        match self {
            TaskId::GauzePick => "T1-1",
            TaskId::NeedlePick => "T1-2",
            TaskId::Electrocoagulation => "T1-3",
            TaskId::GauzePickDistractors => "T2-1",
            TaskId::NeedlePickDistractors => "T2-2",
            TaskId::VesselClipping => "T2-3",
            TaskId::PickAndPlace => "T3-1",
            TaskId::Hemostasis => "T3-2",
        }
    }

    /// The readable name, e.g. "gauze_pick".
    pub fn name(self) -> &'static str {
        match self {
            TaskId::GauzePick => "gauze_pick",
            TaskId::NeedlePick => "needle_pick",
            TaskId::Electrocoagulation => "electrocoagulation",
            TaskId::GauzePickDistractors => "gauze_pick_distractors",
            TaskId::NeedlePickDistractors => "needle_pick_distractors",
            TaskId::VesselClipping => "vessel_clipping",
            TaskId::PickAndPlace => "pick_and_place",
            TaskId::Hemostasis => "hemostasis",
        }
    }

    /// Level 1 (atomic), 2 (conditional) or 3 (composite).
    pub fn level(self) -> u8 {
        match self {
            TaskId::GauzePick | TaskId::NeedlePick | TaskId::Electrocoagulation => 1,
            TaskId::GauzePickDistractors
            | TaskId::NeedlePickDistractors
            | TaskId::VesselClipping => 2,
            TaskId::PickAndPlace | TaskId::Hemostasis => 3,
        }
    }

    /// Step limit: 100 for levels 1 and 2, 150 for level 3.
    pub fn step_limit(self) -> u32 {
        if self.level() == 3 { 150 } else { 100 }
    }

    /// The canonical instruction.
    pub fn instruction(self) -> &'static str {
        match self {
            TaskId::GauzePick | TaskId::GauzePickDistractors => "pick up the gauze",
            TaskId::NeedlePick | TaskId::NeedlePickDistractors => "pick up the needle",
            TaskId::Electrocoagulation => "touch the red blood spot on the kidney",
            TaskId::VesselClipping => "clip the red blood point on the vein",
            TaskId::PickAndPlace => "pick up the gauze and place it on the block",
            TaskId::Hemostasis => {
                "pick up the gauze and place it on the red target point on the spleen"
            }
        }
    }

    /// The scene of an episode with this seed: reference spawn ranges, one distractor at level 2.
    pub fn scene(self, seed: u64) -> SceneSpec {
        let mut rng = SplitMix64::stream(seed, self.code());
        let mut scene = SceneSpec::default();
        let mut uniform_xy =
            |x: (f64, f64), y: (f64, f64)| (rng.uniform(x.0, x.1), rng.uniform(y.0, y.1));
        match self {
            TaskId::GauzePick => {
                let (x, y) = uniform_xy((0.54, 0.56), (-0.01, 0.01));
                scene
                    .objects
                    .push(object("gauze", ObjectKind::Gauze, x, y, 0.0));
            }
            TaskId::NeedlePick => {
                let (x, y) = uniform_xy((0.54, 0.56), (-0.01, 0.01));
                let (yaw_deg, _) = uniform_xy((-90.0, 90.0), (0.0, 0.0));
                scene.objects.push(object(
                    "needle",
                    ObjectKind::Needle,
                    x,
                    y,
                    yaw_deg.to_radians(),
                ));
            }
            TaskId::GauzePickDistractors | TaskId::NeedlePickDistractors | TaskId::PickAndPlace => {
                let (gx, gy) = uniform_xy((0.52, 0.54), (-0.02, 0.0));
                let (ox, oy) = uniform_xy((0.56, 0.58), (0.0, 0.02));
                let (yaw_deg, _) = uniform_xy((-90.0, 90.0), (0.0, 0.0));
                let (target, other, other_name) = match self {
                    TaskId::GauzePickDistractors => {
                        (ObjectKind::Gauze, ObjectKind::Needle, "needle")
                    }
                    TaskId::NeedlePickDistractors => {
                        (ObjectKind::Needle, ObjectKind::Gauze, "gauze")
                    }
                    _ => (ObjectKind::Gauze, ObjectKind::Block, "block"),
                };
                scene
                    .objects
                    .push(object(target.name(), target, gx, gy, yaw_deg.to_radians()));
                let mut other_object = object(other_name, other, ox, oy, 0.0);
                other_object.distractor = self != TaskId::PickAndPlace;
                scene.objects.push(other_object);
            }
            TaskId::Electrocoagulation => {
                let (dx, dy) = uniform_xy((-0.03, 0.03), (-0.02, 0.02));
                let (yaw_deg, shape) = uniform_xy((-15.0, 15.0), (0.0, 1.0));
                let kidney = solid_organ(
                    OrganKind::Kidney,
                    [0.022, 0.04, 0.016],
                    [0.56 + dx * 0.5, dy],
                    yaw_deg,
                    shape,
                );
                let spot = mark_on(
                    &kidney,
                    Vector3::new(-0.1, 0.55, 0.83),
                    "bleeding_spot",
                    MarkColour::Red,
                    0.0024,
                );
                scene.organs.push(kidney);
                scene.marks.push(spot);
            }
            TaskId::VesselClipping => {
                let (dx, dy) = uniform_xy((-0.015, 0.015), (-0.01, 0.01));
                let (shape, order) = uniform_xy((0.0, 1.0), (0.0, 6.0));
                let radius = 0.0025;
                let vessel = OrganSpec {
                    kind: OrganKind::Vessel,
                    world_from_organ: Isometry3::translation(0.55 + dx, dy, TRAY_TOP_Z_M + radius),
                    semi_axes_m: [0.006, 0.07, radius],
                    shape_seed: (shape * u64::MAX as f64) as u64,
                };
                // Three candidate clip sites along the vessel; the red one is the target.
                let colours = match order as u32 {
                    0 => [MarkColour::Red, MarkColour::Yellow, MarkColour::Green],
                    1 => [MarkColour::Yellow, MarkColour::Red, MarkColour::Green],
                    2 => [MarkColour::Yellow, MarkColour::Green, MarkColour::Red],
                    3 => [MarkColour::Red, MarkColour::Blue, MarkColour::Yellow],
                    4 => [MarkColour::Blue, MarkColour::Red, MarkColour::Yellow],
                    _ => [MarkColour::Green, MarkColour::Blue, MarkColour::Red],
                };
                let (path, _) = organ::vessel_path(&vessel, 11);
                for (site, colour) in [3usize, 5, 7].into_iter().zip(colours) {
                    let local = path[site] + Vector3::new(0.0, 0.0, radius);
                    scene.marks.push(MarkSpec {
                        name: format!("{}_clip_site", colour.name()),
                        position_m: (vessel.world_from_organ * nalgebra::Point3::from(local))
                            .coords,
                        radius_m: 0.0012,
                        colour,
                        target: colour == MarkColour::Red,
                    });
                }
                scene.organs.push(vessel);
            }
            TaskId::Hemostasis => {
                let (dx, dy) = uniform_xy((-0.01, 0.01), (-0.015, 0.015));
                let (yaw_deg, shape) = uniform_xy((-10.0, 10.0), (0.0, 1.0));
                let spleen = solid_organ(
                    OrganKind::Spleen,
                    [0.032, 0.06, 0.02],
                    [0.475 + dx, dy],
                    yaw_deg,
                    shape,
                );
                let target = mark_on(
                    &spleen,
                    Vector3::new(0.55, 0.0, 0.83),
                    "bleeding_target",
                    MarkColour::Red,
                    0.0024,
                );
                scene.organs.push(spleen);
                scene.marks.push(target);
                let (x, y) = uniform_xy((0.57, 0.59), (0.0, 0.02));
                scene
                    .objects
                    .push(object("gauze", ObjectKind::Gauze, x, y, 0.0));
            }
        }
        scene
    }
}

/// A kidney or spleen resting on the tray (its flattened base on the pad) at `xy`.
fn solid_organ(
    kind: OrganKind,
    semi_axes_m: [f64; 3],
    xy: [f64; 2],
    yaw_deg: f64,
    shape: f64,
) -> OrganSpec {
    let z = TRAY_TOP_Z_M + organ::BASE_FRACTION * semi_axes_m[2];
    OrganSpec {
        kind,
        world_from_organ: Isometry3::from_parts(
            Translation3::new(xy[0], xy[1], z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
        ),
        semi_axes_m,
        shape_seed: (shape * u64::MAX as f64) as u64,
    }
}

/// A mark on an organ's surface in the organ-frame direction `direction`.
fn mark_on(
    organ_spec: &OrganSpec,
    direction: Vector3<f64>,
    name: &str,
    colour: MarkColour,
    radius_m: f64,
) -> MarkSpec {
    let local = organ::surface_point(organ_spec, direction);
    MarkSpec {
        name: name.to_string(),
        position_m: (organ_spec.world_from_organ * nalgebra::Point3::from(local)).coords,
        radius_m,
        colour,
        target: true,
    }
}

fn object(name: &str, kind: ObjectKind, x: f64, y: f64, yaw_rad: f64) -> ObjectSpec {
    ObjectSpec {
        name: name.to_string(),
        kind,
        distractor: false,
        world_from_object: Isometry3::from_parts(
            Translation3::new(x, y, TRAY_TOP_Z_M + kind.rest_height_m()),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        ),
    }
}

impl fmt::Display for TaskId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for TaskId {
    type Err = UnknownTask;

    /// Accepts the name ("gauze_pick", also with '-'), or the id ("T1-1", any case).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let wanted = text.trim().to_ascii_lowercase().replace('-', "_");
        TaskId::ALL
            .into_iter()
            .find(|t| {
                t.name() == wanted || t.code().to_ascii_lowercase().replace('-', "_") == wanted
            })
            .ok_or_else(|| UnknownTask {
                given: text.to_string(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_codes_parse_back() {
        for task in TaskId::ALL {
            assert_eq!(task.name().parse::<TaskId>(), Ok(task));
            assert_eq!(task.code().parse::<TaskId>(), Ok(task));
            assert_eq!(task.code().to_lowercase().parse::<TaskId>(), Ok(task));
        }
        let error = "gauze_pik".parse::<TaskId>().unwrap_err();
        assert!(error.to_string().contains("gauze_pick (T1-1)"), "{error}");
    }

    #[test]
    fn levels_and_step_limits() {
        let limits: Vec<u32> = TaskId::ALL.iter().map(|t| t.step_limit()).collect();
        assert_eq!(limits, [100, 100, 100, 100, 100, 100, 150, 150]);
    }

    #[test]
    fn spawns_are_seeded_and_within_ranges() {
        for seed in 0..50 {
            let scene = TaskId::GauzePick.scene(seed);
            assert_eq!(scene, TaskId::GauzePick.scene(seed));
            let p = scene.objects[0].world_from_object.translation.vector;
            assert!((0.54..0.56).contains(&p.x) && (-0.01..0.01).contains(&p.y));
        }
        assert_ne!(TaskId::GauzePick.scene(1), TaskId::GauzePick.scene(2));
    }
}
