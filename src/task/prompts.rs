//! The language probes' instructions: the detailed prompt (the target described, distractors
//! and other sites named: "pick up the gauze, not the needle") and the instruction naming an
//! object the scene does not hold (LIBERO-PRO's probe). Both are read off the drawn scene, so
//! they name what is (or is not) there.

use crate::scene::{MarkColour, ObjectKind, SceneSpec};
use crate::task::id::TaskId;

/// `a`, `a or b`, `a, b or c`.
fn either(names: &[String]) -> String {
    match names {
        [] => String::new(),
        [one] => one.clone(),
        [rest @ .., last] => format!("{} or {last}", rest.join(", ")),
    }
}

/// The distractors' kinds, each once, in scene order.
fn distractor_kinds(scene: &SceneSpec) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for object in scene.objects.iter().filter(|o| o.distractor) {
        let name = format!("the {}", object.kind.name());
        if !names.contains(&name) {
            names.push(name);
        }
    }
    names
}

/// The detailed prompt of `task` in `scene` (`target_colour`: T2-3's target site).
pub fn detailed(task: TaskId, scene: &SceneSpec, target_colour: MarkColour) -> String {
    match task {
        TaskId::GauzePick => "pick up the white gauze pad from the tray and lift it".into(),
        TaskId::NeedlePick => {
            "grasp the curved suture needle near its middle and lift it off the tray".into()
        }
        TaskId::Electrocoagulation => {
            "with the jaws closed, touch the red blood spot on the kidney with the instrument tip"
                .into()
        }
        TaskId::GauzePickDistractors | TaskId::NeedlePickDistractors => {
            let target = if task == TaskId::GauzePickDistractors {
                "gauze"
            } else {
                "needle"
            };
            match distractor_kinds(scene).as_slice() {
                [] => format!("pick up the {target}"),
                others => format!("pick up the {target}, not {}", either(others)),
            }
        }
        TaskId::VesselClipping => {
            let c = target_colour.name();
            let others: Vec<String> = (scene.marks.iter())
                .filter(|m| m.colour != target_colour)
                .map(|m| format!("the {} mark", m.colour.name()))
                .collect();
            let site = format!("close the jaws across the vein at the {c} point to clip it");
            if others.is_empty() {
                site
            } else {
                format!("{site}, not at {}", either(&others))
            }
        }
        TaskId::PickAndPlace => {
            "pick up the gauze, carry it over the blue block and release it on top of the block"
                .into()
        }
        TaskId::Hemostasis => {
            "pick up the gauze, carry it to the red target point on the spleen and release it there"
                .into()
        }
    }
}

/// An instruction of `task`'s form naming what `scene` does not hold: another object kind (the
/// first absent of needle, gauze, block; scissors when all are there) or another organ.
pub fn absent_object(task: TaskId, scene: &SceneSpec) -> String {
    let present = |kind: ObjectKind| scene.objects.iter().any(|o| o.kind == kind);
    let absent = [ObjectKind::Needle, ObjectKind::Gauze, ObjectKind::Block]
        .into_iter()
        .find(|&k| !present(k))
        .map_or("scissors", ObjectKind::name);
    match task {
        TaskId::Electrocoagulation => "touch the red blood spot on the spleen".into(),
        TaskId::VesselClipping => "clip the red blood point on the kidney".into(),
        TaskId::PickAndPlace => format!("pick up the {absent} and place it on the block"),
        TaskId::Hemostasis => {
            format!("pick up the {absent} and place it on the red target point on the spleen")
        }
        _ => format!("pick up the {absent}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::{InstructionChoice, TaskConfig};

    #[test]
    fn the_probes_name_what_is_and_is_not_there() {
        let config = |instruction, distractors| TaskConfig {
            instruction,
            distractors,
            ..TaskConfig::default()
        };
        let detailed = TaskId::GauzePickDistractors
            .instance(3, &config(InstructionChoice::Detailed, 1))
            .unwrap();
        assert_eq!(detailed.instruction, "pick up the gauze, not the needle");
        let two = TaskId::NeedlePickDistractors
            .instance(3, &config(InstructionChoice::Detailed, 2))
            .unwrap();
        assert_eq!(
            two.instruction,
            "pick up the needle, not the gauze or the block"
        );
        for task in TaskId::ALL {
            for seed in 0..5 {
                let absent = task
                    .instance(seed, &config(InstructionChoice::AbsentObject, 3))
                    .unwrap();
                let plain = task.instance(seed, &config(InstructionChoice::Canonical, 3));
                // The scene is the canonical one; the instruction names nothing in it.
                assert_eq!(absent.scene, plain.unwrap().scene);
                let named: Vec<&str> = (absent.scene.objects.iter())
                    .map(|o| o.kind.name())
                    .collect();
                let object = absent.instruction.split(' ').nth(3).unwrap_or_default();
                assert!(
                    !named.contains(&object),
                    "{task}: {} names {object}, which is there",
                    absent.instruction
                );
                assert_ne!(absent.instruction, task.instruction());
                let detailed = task
                    .instance(seed, &config(InstructionChoice::Detailed, 1))
                    .unwrap();
                assert_ne!(detailed.instruction, task.instruction());
            }
        }
        let clip = TaskId::VesselClipping
            .instance(0, &config(InstructionChoice::Detailed, 1))
            .unwrap();
        assert!(
            clip.instruction.contains(", not at the "),
            "{}",
            clip.instruction
        );
    }
}
