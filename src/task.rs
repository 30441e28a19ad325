//! The eight SurgVLA-Bench tasks: identifiers, names, levels, step limits, canonical
//! instructions, and seeded scene construction with the reference spawn ranges.
//!
//! Success predicates and expert plans build on these (see `scripted_policies/`). Spawn
//! positions come from a per-task random stream of the episode seed, so a scene is a pure
//! function of (task, seed).

use crate::rng::SplitMix64;
use crate::sim::scene::{ObjectKind, ObjectSpec, OrganKind, OrganSpec, SceneSpec, TRAY_TOP_Z_M};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
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
                scene.objects.push(object(other_name, other, ox, oy, 0.0));
            }
            TaskId::Electrocoagulation | TaskId::VesselClipping | TaskId::Hemostasis => {
                let (dx, dy) = uniform_xy((-0.03, 0.03), (-0.02, 0.02));
                let (kind, center, half) = match self {
                    TaskId::Electrocoagulation => (
                        OrganKind::Kidney,
                        [0.65, 0.0, Z0_M - 0.028],
                        [0.03, 0.055, 0.03],
                    ),
                    TaskId::VesselClipping => (
                        OrganKind::Vessel,
                        [0.556, -0.14, Z0_M - 0.003],
                        [0.004, 0.06, 0.004],
                    ),
                    _ => (
                        OrganKind::Spleen,
                        [0.44, 0.0, Z0_M - 0.04],
                        [0.05, 0.03, 0.045],
                    ),
                };
                scene.organs.push(OrganSpec {
                    kind,
                    world_from_organ: Isometry3::translation(
                        center[0] + dx,
                        center[1] + dy,
                        center[2],
                    ),
                    half_extents_m: half,
                });
                if self == TaskId::Hemostasis {
                    let (x, y) = uniform_xy((0.57, 0.59), (0.0, 0.02));
                    scene
                        .objects
                        .push(object("gauze", ObjectKind::Gauze, x, y, 0.0));
                }
            }
        }
        scene
    }
}

fn object(name: &str, kind: ObjectKind, x: f64, y: f64, yaw_rad: f64) -> ObjectSpec {
    ObjectSpec {
        name: name.to_string(),
        kind,
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
