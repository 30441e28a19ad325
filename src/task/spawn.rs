//! Seeded scene construction: spawn ranges, distractors, instruction choice.
//!
//! Every random draw comes from a per-task stream of the episode seed, in a fixed order, so a
//! [`TaskInstance`] is a pure function of (task, seed, config). Objects are placed by rejection
//! sampling ([`placement`](super::placement)) so that no two footprints come within
//! [`CLEARANCE_M`] of each other and every
//! footprint stays on the tray pad: a scene never starts with objects touching, so "the
//! distractor did not move" means the instrument left it alone.

use crate::rng::SplitMix64;
use crate::scene::{MarkColour, ObjectKind, OrganKind, SceneSpec};
use crate::task::id::TaskId;
pub use crate::task::instance::{
    InstructionChoice, MAX_DISTRACTORS, Range, SpawnRanges, TaskConfig, TaskInstance,
};
pub use crate::task::placement::CLEARANCE_M;
use crate::task::placement::{Placer, organ_outline, unreachable_target, vessel_with_sites};
use nalgebra::Vector3;

/// The spawn is impossible: the ranges leave no room for the objects, or put the target out of
/// the instrument's reach.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{task}: no valid scene in {MAX_LAYOUTS} layouts (seed {seed}); last problem: {problem}. Narrow or move the spawn ranges, or use fewer distractors"
)]
pub struct SpawnError {
    pub task: TaskId,
    pub seed: u64,
    pub problem: String,
}

/// A spawn that cannot be drawn fails the work (the ranges are the program's or a plan's).
impl crate::error::HasKind for SpawnError {
    fn kind(&self) -> crate::error::ErrorKind {
        crate::error::ErrorKind::Failed
    }
}

/// Most whole-scene redraws before the spawn is declared impossible.
pub const MAX_LAYOUTS: usize = 50;

/// The target object (`target`, first) in the primary range and its distractors (the other two
/// kinds in turn, `config.distractors` of them) in their slots.
fn place_with_distractors(
    placer: &mut Placer<'_>,
    scene: &mut SceneSpec,
    target: ObjectKind,
    (config, spawn): (&TaskConfig, &SpawnRanges),
    yaw_rad: f64,
) -> Result<(), String> {
    let others = if target == ObjectKind::Gauze {
        [ObjectKind::Needle, ObjectKind::Block]
    } else {
        [ObjectKind::Gauze, ObjectKind::Block]
    };
    let range = (spawn.primary_x_m, spawn.primary_y_m);
    scene
        .objects
        .push(placer.place(target.name(), target, range, Some(yaw_rad))?);
    let slots = [
        (spawn.secondary_x_m, spawn.secondary_y_m),
        ((0.56, 0.58), (-0.045, -0.025)),
        ((0.505, 0.525), (0.02, 0.04)),
    ];
    let count = config.distractors.clamp(1, MAX_DISTRACTORS);
    for (i, slot) in slots.into_iter().take(count).enumerate() {
        let kind = others[i % 2];
        let name = format!("{}_distractor_{}", kind.name(), i + 1);
        let mut object = placer.place(&name, kind, slot, None)?;
        object.distractor = true;
        scene.objects.push(object);
    }
    Ok(())
}

/// The vessel with its clip sites; returns the target site's index (the red one, or drawn when
/// `config.vary_clip_target`).
fn place_vessel(
    placer: &mut Placer<'_>,
    scene: &mut SceneSpec,
    config: &TaskConfig,
    spawn: &SpawnRanges,
) -> usize {
    let [x, y] = placer.xy(spawn.primary_x_m, spawn.primary_y_m);
    let shape = placer.rng.next_f64();
    let order = placer.rng.next_f64();
    let target_draw = placer.rng.next_f64();
    let (vessel, marks) = vessel_with_sites(x, y, shape, order);
    let target = if config.vary_clip_target {
        ((target_draw * 3.0) as usize).min(2)
    } else {
        marks
            .iter()
            .position(|m| m.colour == MarkColour::Red)
            .unwrap_or(0)
    };
    scene.marks = marks;
    scene.marks[target].target = true;
    scene.organs.push(vessel);
    target
}

/// The spleen with its bleeding target, and the gauze off the spleen.
fn place_hemostasis(
    placer: &mut Placer<'_>,
    scene: &mut SceneSpec,
    spawn: &SpawnRanges,
    yaw_rad: f64,
) -> Result<(), String> {
    let (spleen, target) = placer.organ_with_mark(
        OrganKind::Spleen,
        SPLEEN_SEMI_AXES_M,
        spawn,
        yaw_rad,
        (Vector3::new(0.55, 0.0, 0.83), "bleeding_target"),
    );
    // The gauze must not start on the spleen.
    placer.placed.push(organ_outline(&spleen));
    scene.marks.push(target);
    scene.organs.push(spleen);
    let range = (spawn.secondary_x_m, spawn.secondary_y_m);
    scene
        .objects
        .push(placer.place("gauze", ObjectKind::Gauze, range, Some(0.0))?);
    Ok(())
}

impl TaskId {
    /// The reference spawn ranges (`tasks.md`), with our choices where the reference cannot be
    /// reached (the spleen sits 25 mm further +x so its target lies inside the workspace).
    pub fn default_spawn(self) -> SpawnRanges {
        let ranges = |px: Range, py: Range, sx: Range, sy: Range, yaw: Range| SpawnRanges {
            primary_x_m: px,
            primary_y_m: py,
            secondary_x_m: sx,
            secondary_y_m: sy,
            yaw_deg: yaw,
        };
        let none = (0.0, 0.0);
        match self {
            TaskId::GauzePick => ranges((0.54, 0.56), (-0.01, 0.01), none, none, none),
            TaskId::NeedlePick => ranges((0.54, 0.56), (-0.01, 0.01), none, none, (-90.0, 90.0)),
            TaskId::Electrocoagulation => {
                ranges((0.545, 0.575), (-0.02, 0.02), none, none, (-15.0, 15.0))
            }
            TaskId::GauzePickDistractors | TaskId::NeedlePickDistractors | TaskId::PickAndPlace => {
                ranges(
                    (0.52, 0.54),
                    (-0.02, 0.0),
                    (0.56, 0.58),
                    (0.0, 0.02),
                    (-90.0, 90.0),
                )
            }
            // The vessel along x: its far end stays on the pad (x <= 0.597), its sites in the
            // workspace.
            TaskId::VesselClipping => ranges((0.535, 0.55), (-0.015, 0.015), none, none, none),
            // The spleen's centre range puts the bleeding target where the reference has it:
            // x 0.532..0.552, y +-0.03, z ~0.705.
            TaskId::Hemostasis => ranges(
                (0.522, 0.542),
                (-0.03, 0.03),
                (0.57, 0.59),
                (0.0, 0.02),
                (-10.0, 10.0),
            ),
        }
    }

    /// The scene of episode `seed` with the default configuration.
    pub fn scene(self, seed: u64) -> Result<crate::scene::SceneSpec, SpawnError> {
        Ok(self.instance(seed, &TaskConfig::default())?.scene)
    }

    /// The episode's setup with the default spawn ranges scaled by `config.spawn_scale`.
    pub fn instance(self, seed: u64, config: &TaskConfig) -> Result<TaskInstance, SpawnError> {
        self.try_instance(
            seed,
            config,
            &self.default_spawn().scaled(config.spawn_scale),
        )
    }

    /// The episode's setup with explicit spawn ranges. A layout whose objects cannot be placed
    /// clear of each other, or whose target lies outside the workspace, is redrawn whole (the
    /// first layout is kept whenever it is valid).
    pub fn try_instance(
        self,
        seed: u64,
        config: &TaskConfig,
        spawn: &SpawnRanges,
    ) -> Result<TaskInstance, SpawnError> {
        let mut rng = SplitMix64::stream(seed, self.code());
        let mut problem = String::new();
        for _ in 0..MAX_LAYOUTS {
            match self.layout(&mut rng, seed, config, spawn) {
                Ok(mut instance) => match unreachable_target(&instance) {
                    None => {
                        instance.instruction = instruction(self, &instance, config.instruction);
                        return Ok(instance);
                    }
                    Some(why) => problem = why,
                },
                Err(why) => problem = why,
            }
        }
        Err(SpawnError {
            task: self,
            seed,
            problem,
        })
    }

    /// One drawn layout (without the instruction).
    fn layout(
        self,
        rng: &mut SplitMix64,
        seed: u64,
        config: &TaskConfig,
        spawn: &SpawnRanges,
    ) -> Result<TaskInstance, String> {
        let mut instance = TaskInstance {
            task: self,
            seed,
            scene: SceneSpec::default(),
            instruction: String::new(),
            target_object: None,
            support_object: None,
            target_mark: None,
        };
        let yaw_rad = rng.uniform(spawn.yaw_deg.0, spawn.yaw_deg.1).to_radians();
        let mut placer = Placer {
            rng,
            placed: Vec::new(),
        };
        let scene = &mut instance.scene;
        match self {
            TaskId::GauzePick | TaskId::NeedlePick => {
                let kind = if self == TaskId::GauzePick {
                    ObjectKind::Gauze
                } else {
                    ObjectKind::Needle
                };
                let yaw = if kind == ObjectKind::Needle {
                    yaw_rad
                } else {
                    0.0
                };
                let range = (spawn.primary_x_m, spawn.primary_y_m);
                scene
                    .objects
                    .push(placer.place(kind.name(), kind, range, Some(yaw))?);
                instance.target_object = Some(0);
            }
            TaskId::GauzePickDistractors | TaskId::NeedlePickDistractors => {
                let target = if self == TaskId::GauzePickDistractors {
                    ObjectKind::Gauze
                } else {
                    ObjectKind::Needle
                };
                place_with_distractors(&mut placer, scene, target, (config, spawn), yaw_rad)?;
                instance.target_object = Some(0);
            }
            TaskId::PickAndPlace => {
                let range = (spawn.primary_x_m, spawn.primary_y_m);
                scene.objects.push(placer.place(
                    "gauze",
                    ObjectKind::Gauze,
                    range,
                    Some(yaw_rad),
                )?);
                let range = (spawn.secondary_x_m, spawn.secondary_y_m);
                scene
                    .objects
                    .push(placer.place("block", ObjectKind::Block, range, Some(0.0))?);
                instance.target_object = Some(0);
                instance.support_object = Some(1);
            }
            TaskId::Electrocoagulation => {
                let (kidney, spot) = placer.organ_with_mark(
                    OrganKind::Kidney,
                    [0.022, 0.04, 0.016],
                    spawn,
                    yaw_rad,
                    (Vector3::new(-0.1, 0.55, 0.83), "bleeding_spot"),
                );
                scene.organs.push(kidney);
                scene.marks.push(spot);
                instance.target_mark = Some(0);
                scene.tip_start_m = Some(electrocoagulation_start(seed));
            }
            TaskId::VesselClipping => {
                instance.target_mark = Some(place_vessel(&mut placer, scene, config, spawn));
            }
            TaskId::Hemostasis => {
                place_hemostasis(&mut placer, scene, spawn, yaw_rad)?;
                instance.target_object = Some(0);
                instance.target_mark = Some(0);
            }
        }
        Ok(instance)
    }
}

/// T1-3's start: the reference randomises the start pose's x by +-4 cm; the -x half lies
/// outside the workspace (x >= 0.496 m), from which the first command would jump the tip back
/// in, so ours draws the +x half, x 0.50..0.54 (own stream: the scene does not change).
fn electrocoagulation_start(seed: u64) -> Vector3<f64> {
    let mut rng = SplitMix64::stream(seed, "start pose");
    Vector3::new(rng.uniform(0.50, 0.54), 0.05, 0.7202)
}

/// The spleen of T3-2 (semi-axes, metres): 56 x 120 x 32 mm before its base is flattened (it
/// stands 27 mm above the pad), so the target on its upper surface is at z ~0.705.
const SPLEEN_SEMI_AXES_M: [f64; 3] = [0.028, 0.06, 0.016];

/// The instruction of an instance, drawn from its own stream so the scene does not depend on
/// the instruction choice.
fn instruction(task: TaskId, instance: &TaskInstance, choice: InstructionChoice) -> String {
    let mut rng = SplitMix64::stream(instance.seed, "instruction");
    let colour = instance
        .target_mark
        .and_then(|i| instance.scene.marks.get(i))
        .map_or(MarkColour::Red, |m| m.colour);
    let (canonical, paraphrases): (String, Vec<String>) =
        if task == TaskId::VesselClipping && colour != MarkColour::Red {
            let c = colour.name();
            (
                format!("clip the {c} point on the vein"),
                vec![
                    format!("clamp the {c} point on the vessel"),
                    format!("close the jaws across the vein at the {c} mark"),
                ],
            )
        } else {
            (
                task.instruction().to_string(),
                task.paraphrases().iter().map(|p| p.to_string()).collect(),
            )
        };
    let pick = |options: &[String], draw: f64| {
        let i = ((draw * options.len() as f64) as usize).min(options.len() - 1);
        options[i].clone()
    };
    match choice {
        InstructionChoice::Canonical => canonical,
        InstructionChoice::Detailed => super::prompts::detailed(task, &instance.scene, colour),
        InstructionChoice::AbsentObject => super::prompts::absent_object(task, &instance.scene),
        InstructionChoice::Paraphrase => pick(&paraphrases, rng.next_f64()),
        InstructionChoice::Mixed => {
            let mut all = vec![canonical];
            all.extend(paraphrases);
            pick(&all, rng.next_f64())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::placement::footprint;

    #[test]
    fn spawns_are_seeded_within_ranges_and_clear_of_each_other() {
        for task in TaskId::ALL {
            let spawn = task.default_spawn();
            for seed in 0..40 {
                let instance = task.instance(seed, &TaskConfig::default()).unwrap();
                assert_eq!(
                    instance,
                    task.instance(seed, &TaskConfig::default()).unwrap()
                );
                if let Some(target) = instance.target_object {
                    let p = instance.scene.objects[target].world_from_object.translation;
                    let (x, y) = (spawn.primary_x_m, spawn.primary_y_m);
                    let (x, y) = if task == TaskId::Hemostasis {
                        (spawn.secondary_x_m, spawn.secondary_y_m)
                    } else {
                        (x, y)
                    };
                    assert!((x.0..=x.1).contains(&p.x) && (y.0..=y.1).contains(&p.y));
                }
                let prints: Vec<_> = instance.scene.objects.iter().map(footprint).collect();
                for (i, a) in prints.iter().enumerate() {
                    for b in &prints[i + 1..] {
                        let gap = a
                            .iter()
                            .flat_map(|p| b.iter().map(move |q| (p - q).norm()))
                            .fold(f64::INFINITY, f64::min);
                        assert!(gap >= CLEARANCE_M, "{task} seed {seed}: gap {gap}");
                    }
                }
            }
        }
        assert_ne!(TaskId::GauzePick.scene(1), TaskId::GauzePick.scene(2));
    }

    #[test]
    fn distractor_count_is_configurable_and_names_are_unique() {
        for distractors in 1..=MAX_DISTRACTORS {
            let config = TaskConfig {
                distractors,
                ..TaskConfig::default()
            };
            for seed in 0..20 {
                let instance = TaskId::NeedlePickDistractors
                    .instance(seed, &config)
                    .unwrap();
                let objects = &instance.scene.objects;
                assert_eq!(objects.len(), distractors + 1);
                assert_eq!(objects.iter().filter(|o| o.distractor).count(), distractors);
                assert!(
                    objects
                        .iter()
                        .filter(|o| o.distractor)
                        .all(|o| o.kind != ObjectKind::Needle)
                );
                let names: std::collections::BTreeSet<_> =
                    objects.iter().map(|o| &o.name).collect();
                assert_eq!(names.len(), objects.len());
            }
        }
    }

    #[test]
    fn clip_target_varies_and_the_instruction_names_its_colour() {
        let mut colours = std::collections::BTreeSet::new();
        for seed in 0..30 {
            let instance = TaskId::VesselClipping
                .instance(seed, &TaskConfig::default())
                .unwrap();
            let mark = &instance.scene.marks[instance.target_mark.unwrap()];
            assert!(mark.target);
            assert_eq!(instance.scene.marks.iter().filter(|m| m.target).count(), 1);
            assert!(
                instance.instruction.contains(mark.colour.name()),
                "{}",
                instance.instruction
            );
            colours.insert(mark.colour.name());
        }
        assert!(colours.len() >= 3, "{colours:?}");
        let fixed = TaskConfig {
            vary_clip_target: false,
            ..TaskConfig::default()
        };
        let instance = TaskId::VesselClipping.instance(3, &fixed).unwrap();
        assert_eq!(instance.instruction, "clip the red blood point on the vein");
    }

    #[test]
    fn instruction_choice_is_seeded_and_leaves_the_scene_alone() {
        let canonical = TaskId::GauzePick
            .instance(4, &TaskConfig::default())
            .unwrap();
        assert_eq!(canonical.instruction, "pick up the gauze");
        let paraphrase = TaskConfig {
            instruction: InstructionChoice::Paraphrase,
            ..TaskConfig::default()
        };
        let mut seen = std::collections::BTreeSet::new();
        for seed in 0..30 {
            let instance = TaskId::GauzePick.instance(seed, &paraphrase).unwrap();
            assert!(
                TaskId::GauzePick
                    .paraphrases()
                    .contains(&instance.instruction.as_str())
            );
            assert_eq!(instance.scene, TaskId::GauzePick.scene(seed).unwrap());
            seen.insert(instance.instruction);
        }
        assert!(seen.len() > 1);
    }

    #[test]
    fn only_electrocoagulation_randomises_the_start_pose() {
        let mut xs = Vec::new();
        for seed in 0..50 {
            let instance = TaskId::Electrocoagulation
                .instance(seed, &TaskConfig::default())
                .unwrap();
            let start = instance.scene.tip_start_m.expect("a start pose");
            assert!((0.50..=0.54).contains(&start.x), "{start:?}");
            assert_eq!((start.y, start.z), (0.05, 0.7202));
            xs.push(start.x);
            let other = TaskId::GauzePick
                .instance(seed, &TaskConfig::default())
                .unwrap();
            assert_eq!(other.scene.tip_start_m, None);
        }
        let spread = xs.iter().cloned().fold(f64::MIN, f64::max)
            - xs.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 0.03, "{spread}");
    }

    #[test]
    fn the_hemostasis_target_is_where_the_reference_puts_it() {
        // Reference: x 0.532..0.552, y +-0.03, z 0.705; the spleen's yaw and surface noise add a
        // few millimetres.
        let (mut low, mut high) = ([f64::MAX; 3], [f64::MIN; 3]);
        for seed in 0..200 {
            let instance = TaskId::Hemostasis
                .instance(seed, &TaskConfig::default())
                .unwrap();
            let target = instance.scene.marks[0].position_m;
            for axis in 0..3 {
                low[axis] = low[axis].min(target[axis]);
                high[axis] = high[axis].max(target[axis]);
            }
            let gauze = instance.scene.objects[0]
                .world_from_object
                .translation
                .vector;
            assert!(
                gauze.x >= 0.57 && gauze.x <= 0.59,
                "seed {seed}: gauze x {}",
                gauze.x
            );
        }
        assert!(
            low[0] > 0.528 && high[0] < 0.556,
            "x {:.4}..{:.4}",
            low[0],
            high[0]
        );
        assert!(
            low[1] > -0.036 && high[1] < 0.036,
            "y {:.4}..{:.4}",
            low[1],
            high[1]
        );
        assert!(high[1] - low[1] > 0.045, "y spans the reference's range");
        assert!(
            low[2] > 0.699 && high[2] < 0.711,
            "z {:.4}..{:.4}",
            low[2],
            high[2]
        );
    }

    #[test]
    fn impossible_ranges_are_an_error_not_a_hang() {
        let mut spawn = TaskId::GauzePickDistractors.default_spawn();
        spawn.secondary_x_m = spawn.primary_x_m;
        spawn.secondary_y_m = spawn.primary_y_m;
        let spawn = spawn.scaled(0.0);
        let error = TaskId::GauzePickDistractors
            .try_instance(1, &TaskConfig::default(), &spawn)
            .unwrap_err();
        assert!(error.to_string().contains("needle_distractor_1"), "{error}");
        // Targets beyond the instrument's reach are redrawn; wide ranges still spawn in reach.
        let wide = TaskConfig {
            spawn_scale: 3.0,
            ..TaskConfig::default()
        };
        for task in [TaskId::Electrocoagulation, TaskId::Hemostasis] {
            for seed in 0..30 {
                let instance = task.instance(seed, &wide).unwrap();
                assert_eq!(unreachable_target(&instance), None);
            }
        }
        let mut far = TaskId::Hemostasis.default_spawn();
        far.primary_x_m = (0.40, 0.41);
        let error = TaskId::Hemostasis
            .try_instance(1, &TaskConfig::default(), &far)
            .unwrap_err();
        assert!(error.to_string().contains("out of reach"), "{error}");
    }
}
