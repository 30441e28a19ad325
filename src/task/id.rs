//! Which task: [`TaskId`], its code, name, level, step limit and instructions, and the
//! reference workspace floor the scenes are placed on.

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

    /// The canonical instruction (for T2-3 with the red site as the target).
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

    /// Paraphrases of the canonical instruction (the robustness study's first, then ours).
    pub fn paraphrases(self) -> &'static [&'static str] {
        match self {
            TaskId::GauzePick | TaskId::GauzePickDistractors => &[
                "lift the gauze",
                "grasp the gauze and lift it",
                "take the gauze off the tray",
            ],
            TaskId::NeedlePick | TaskId::NeedlePickDistractors => &[
                "lift the needle",
                "grasp the suture needle and lift it",
                "take the needle off the tray",
            ],
            TaskId::Electrocoagulation => &[
                "contact the red blood spot on the kidney",
                "touch the bleeding spot on the kidney with the closed jaws",
                "put the instrument tip on the red spot on the kidney",
            ],
            TaskId::VesselClipping => &[
                "clamp the bleeding point on the vessel",
                "close the jaws across the vein at the red mark",
            ],
            TaskId::PickAndPlace => &[
                "put the gauze on the block",
                "move the gauze onto the block",
            ],
            TaskId::Hemostasis => &[
                "place the gauze on the bleeding point on the spleen",
                "press the gauze onto the red target on the spleen",
            ],
        }
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

/// A task list that names something that is neither a task nor a level.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown task '{given}'; expected all, a level (L1, L2, L3; level1 ...) or tasks: {}", TaskId::ALL.iter().map(|t| format!("{} ({})", t.name(), t.code())).collect::<Vec<_>>().join(", "))]
pub struct UnknownTasks {
    pub given: String,
}

/// The level a word names: `L1`, `level1`, `level-1`, `level_1` (any case), 1 to 3.
fn level_of(word: &str) -> Option<u8> {
    let word = word.trim().to_ascii_lowercase();
    let digits = word
        .strip_prefix("level")
        .or_else(|| word.strip_prefix('l'))?
        .trim_start_matches(['-', '_']);
    digits.parse().ok().filter(|l| (1..=3).contains(l))
}

/// A task list as users write it: `all`, or comma-separated tasks (ids like `T1-1` or names
/// like `gauze_pick`) and levels (`L1`, `level1`: that level's tasks), mixed, in the order
/// given. A level adds the tasks not listed yet; a task named again is kept twice, for the
/// collection's check to refuse by name.
pub fn parse_task_list(text: &str) -> Result<Vec<TaskId>, UnknownTasks> {
    if text.trim().eq_ignore_ascii_case("all") {
        return Ok(TaskId::ALL.to_vec());
    }
    let mut tasks: Vec<TaskId> = Vec::new();
    for word in text.split(',') {
        match (word.parse::<TaskId>(), level_of(word)) {
            (Ok(task), _) => tasks.push(task),
            (Err(_), Some(level)) => {
                for task in TaskId::ALL.into_iter().filter(|t| t.level() == level) {
                    if !tasks.contains(&task) {
                        tasks.push(task);
                    }
                }
            }
            (Err(_), None) => {
                return Err(UnknownTasks {
                    given: word.trim().to_string(),
                });
            }
        }
    }
    Ok(tasks)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_lists_take_levels_mixed_with_tasks() {
        let codes = |text: &str| -> Vec<&str> {
            parse_task_list(text)
                .unwrap()
                .into_iter()
                .map(TaskId::code)
                .collect()
        };
        assert_eq!(codes("L1"), ["T1-1", "T1-2", "T1-3"]);
        assert_eq!(codes("level3,T1-1"), ["T3-1", "T3-2", "T1-1"]);
        assert_eq!(
            codes("T2-1,level-2,l1"),
            ["T2-1", "T2-2", "T2-3", "T1-1", "T1-2", "T1-3"]
        );
        assert_eq!(codes("ALL").len(), 8);
        let error = parse_task_list("L4").unwrap_err().to_string();
        assert!(
            error.contains("'L4'") && error.contains("L1, L2, L3"),
            "{error}"
        );
        assert!(parse_task_list("T1-1,nothing").is_err());
    }

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
}
