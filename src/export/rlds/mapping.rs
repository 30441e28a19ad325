//! How another tool's RLDS keys become LeRobot's features: the instruction, one `action`, one
//! `observation.state`. Open X-Embodiment datasets name these differently (OpenVLA's
//! `oxe/configs.py` and `oxe/transforms.py` list them per dataset): fractal / RT-1 keeps its
//! instruction at `observation/natural_language_instruction` and its action as a dict of
//! `world_vector`, `rotation_delta`, `gripper_closedness_action`, ...; language_table stores
//! the instruction as UTF-8 byte codes in an int32 tensor; taco_play's action is
//! `rel_actions_world`. [`Mapping::of`] finds them by key, not by dataset name, so a dataset
//! following a published convention under another name is read the same way. Values are never
//! changed: an action dict's parts are concatenated in a stated order (each element named after
//! its part), booleans and integers joining a float vector become 0/1 and their value. What no
//! rule takes is carried under its own name (see `foreign.rs`).

use crate::export::rlds::generic::Leaf;
pub use crate::export::source::Joined;
use std::collections::BTreeMap;

/// Where a dataset keeps its instruction, most common first.
const INSTRUCTION_KEYS: [&str; 5] = [
    "steps/language_instruction",
    "steps/observation/natural_language_instruction",
    "steps/observation/language_instruction",
    "steps/observation/instruction",
    "steps/natural_language_instruction",
];

/// An action dict's parts, in the order OpenVLA concatenates them: the first rule whose first
/// part the dict holds gives the action (its other parts when present).
const ACTION_RULES: [&[&str]; 3] = [
    // taco_play: three 7-D vectors; OpenVLA trains on the relative world-frame one.
    &["rel_actions_world"],
    // fractal, kuka, bridge (OXE), jaco_play, berkeley_autolab_ur5, toto, viola, ...
    &[
        "world_vector",
        "rotation_delta",
        "gripper_closedness_action",
        "open_gripper",
    ],
    &["actions"],
];

/// Parts of an action dict that are never the action itself (a flag, not a motion).
const NOT_ACTION: [&str; 1] = ["terminate_episode"];

/// Observation keys that make the state when the dataset has no `observation/state`, the first
/// rule whose first key is present winning (OpenVLA's `state_obs_keys`).
const STATE_RULES: [&[&str]; 7] = [
    &["base_pose_tool_reached", "gripper_closed"],
    &["robot_obs"],
    &["end_effector_cartesian_pos"],
    &["robot_state"],
    &["joint_states", "gripper_states"],
    &["effector_translation"],
    &["proprio"],
];

/// Where a dataset's instruction is and how it is stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Instruction {
    pub key: String,
    /// UTF-8 byte codes in an integer tensor, zero-padded (language_table), not a text.
    pub codes: bool,
}

/// The keys a dataset's instruction, action and state are read from.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Mapping {
    pub instruction: Option<Instruction>,
    pub joined: Vec<Joined>,
}

fn numeric(leaf: &Leaf) -> bool {
    matches!(leaf, Leaf::Tensor { dtype, .. } if dtype != "string")
}

fn integer(leaf: &Leaf) -> bool {
    matches!(leaf, Leaf::Tensor { dtype, .. } if dtype.starts_with("int") || dtype.starts_with("uint"))
}

impl Mapping {
    /// The mapping of a dataset with these leaves (see the module's rules).
    pub fn of(leaves: &BTreeMap<String, Leaf>) -> Mapping {
        let instruction = INSTRUCTION_KEYS.iter().find_map(|key| {
            let codes = match leaves.get(*key)? {
                Leaf::Text => false,
                leaf if integer(leaf) => true,
                _ => return None,
            };
            Some(Instruction {
                key: key.to_string(),
                codes,
            })
        });
        let mut joined = Vec::new();
        if let Some(keys) = action_keys(leaves) {
            joined.push(Joined {
                name: "action".into(),
                keys,
                names: Vec::new(),
            });
        }
        if !leaves.contains_key("steps/observation/state") {
            let present = |part: &str| {
                leaves
                    .get(&format!("steps/observation/{part}"))
                    .is_some_and(numeric)
            };
            let rule = STATE_RULES.iter().find(|rule| present(rule[0]));
            if let Some(rule) = rule {
                joined.push(Joined {
                    name: "observation.state".into(),
                    keys: (rule.iter().filter(|part| present(part)))
                        .map(|part| format!("steps/observation/{part}"))
                        .collect(),
                    names: Vec::new(),
                });
            }
        }
        Mapping {
            instruction,
            joined,
        }
    }

    /// The mapping with a map file's features (`convert --map`) in place of the rules': a
    /// feature named `task` says where the instruction is (a text, or integer byte codes);
    /// any other replaces the rules' feature of its name or is added. Every key must be one
    /// of `leaves`' numeric ones (the instruction's: a text or integers); `Err` says which is
    /// not and lists the dataset's keys.
    pub fn with(
        mut self,
        map: &[Joined],
        leaves: &BTreeMap<String, Leaf>,
    ) -> Result<Mapping, String> {
        let listing = || {
            let keys: Vec<&str> = (leaves.keys())
                .filter(|k| k.starts_with("steps/"))
                .map(String::as_str)
                .collect();
            keys.join(", ")
        };
        for feature in map {
            if feature.name == "task" {
                let [key] = feature.keys.as_slice() else {
                    return Err("the task is one key".into());
                };
                let codes = match leaves.get(key) {
                    Some(Leaf::Text) => false,
                    Some(leaf) if integer(leaf) => true,
                    _ => {
                        return Err(format!(
                            "task: {key} is not a text or integer key of the dataset, which has {}",
                            listing()
                        ));
                    }
                };
                self.instruction = Some(Instruction {
                    key: key.clone(),
                    codes,
                });
                continue;
            }
            if let Some(key) = (feature.keys.iter()).find(|k| !leaves.get(*k).is_some_and(numeric))
            {
                return Err(format!(
                    "{}: {key} is not a numeric key of the dataset, which has {}",
                    feature.name,
                    listing()
                ));
            }
            let values: usize = (feature.keys.iter())
                .map(|k| match leaves.get(k) {
                    Some(Leaf::Tensor { elements, .. }) => *elements,
                    _ => 0,
                })
                .sum();
            if !feature.names.is_empty() && feature.names.len() != values {
                return Err(format!(
                    "{}: {} names for {values} values",
                    feature.name,
                    feature.names.len()
                ));
            }
            self.joined.retain(|j| j.name != feature.name);
            self.joined.push(feature.clone());
        }
        Ok(self)
    }

    /// Whether `key` is read by the mapping (not carried under its own name).
    pub fn takes(&self, key: &str) -> bool {
        self.instruction.as_ref().is_some_and(|i| i.key == key)
            || self.joined.iter().any(|j| j.keys.iter().any(|k| k == key))
    }

    /// One line per joined feature: "action = steps/action/world_vector + ...".
    pub fn describe(&self) -> Vec<String> {
        let mut lines: Vec<String> = (self.instruction.iter())
            .map(|i| {
                let codes = if i.codes { " (UTF-8 byte codes)" } else { "" };
                format!("the task is {}{codes}", i.key)
            })
            .collect();
        for joined in &self.joined {
            lines.push(format!("{} = {}", joined.name, joined.keys.join(" + ")));
        }
        lines
    }
}

/// The keys of an action dict's parts that make `action`; None when `steps/action` is one
/// tensor (it is `action` as it is) or holds no numeric part.
fn action_keys(leaves: &BTreeMap<String, Leaf>) -> Option<Vec<String>> {
    if leaves.contains_key("steps/action") {
        return None;
    }
    let part = |name: &str| format!("steps/action/{name}");
    let numeric_part = |name: &str| leaves.get(&part(name)).is_some_and(numeric);
    for rule in ACTION_RULES {
        if numeric_part(rule[0]) {
            let parts = rule.iter().filter(|p| numeric_part(p));
            return Some(parts.map(|p| part(p)).collect());
        }
    }
    // No published convention: every numeric part but a termination flag, in key order.
    let keys: Vec<String> = (leaves.iter())
        .filter(|(key, leaf)| {
            key.strip_prefix("steps/action/")
                .is_some_and(|name| !name.contains('/') && !NOT_ACTION.contains(&name))
                && numeric(leaf)
        })
        .map(|(key, _)| key.clone())
        .collect();
    (!keys.is_empty()).then_some(keys)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(dtype: &str, elements: usize) -> Leaf {
        Leaf::Tensor {
            dtype: dtype.into(),
            elements,
            dims: vec![elements],
        }
    }

    fn leaves(entries: &[(&str, Leaf)]) -> BTreeMap<String, Leaf> {
        (entries.iter())
            .map(|(k, l)| (format!("steps/{k}"), l.clone()))
            .collect()
    }

    /// fractal20220817_data's keys (TFDS catalogue): the RT-1 action dict, the instruction
    /// under observation, no observation/state.
    #[test]
    fn fractal_maps_as_openvla_reads_it() {
        let mapping = Mapping::of(&leaves(&[
            ("action/base_displacement_vector", tensor("float32", 2)),
            ("action/gripper_closedness_action", tensor("float32", 1)),
            ("action/rotation_delta", tensor("float32", 3)),
            ("action/terminate_episode", tensor("int32", 3)),
            ("action/world_vector", tensor("float32", 3)),
            ("observation/base_pose_tool_reached", tensor("float32", 7)),
            ("observation/gripper_closed", tensor("float32", 1)),
            ("observation/natural_language_instruction", Leaf::Text),
        ]));
        assert_eq!(
            mapping.describe(),
            [
                "the task is steps/observation/natural_language_instruction",
                "action = steps/action/world_vector + steps/action/rotation_delta + steps/action/gripper_closedness_action",
                "observation.state = steps/observation/base_pose_tool_reached + steps/observation/gripper_closed",
            ]
        );
        assert!(!mapping.takes("steps/action/terminate_episode"));
        assert!(!mapping.takes("steps/action/base_displacement_vector"));
    }

    #[test]
    fn other_conventions_and_none() {
        let taco = Mapping::of(&leaves(&[
            ("action/actions", tensor("float32", 7)),
            ("action/rel_actions_world", tensor("float32", 7)),
            ("action/terminate_episode", tensor("float32", 1)),
            ("observation/robot_obs", tensor("float32", 15)),
        ]));
        assert_eq!(taco.joined[0].keys, ["steps/action/rel_actions_world"]);
        assert_eq!(taco.joined[1].keys, ["steps/observation/robot_obs"]);
        let table = Mapping::of(&leaves(&[
            ("action", tensor("float32", 2)),
            ("observation/instruction", tensor("int32", 512)),
            ("observation/effector_translation", tensor("float32", 2)),
        ]));
        assert_eq!(
            table.instruction,
            Some(Instruction {
                key: "steps/observation/instruction".into(),
                codes: true
            })
        );
        assert_eq!(table.joined.len(), 1, "action is one tensor already");
        let unknown = Mapping::of(&leaves(&[
            ("action/b", tensor("float32", 2)),
            ("action/a", tensor("bool", 1)),
            ("action/terminate_episode", tensor("int32", 1)),
            ("action/note", tensor("string", 1)),
            ("observation/state", tensor("float32", 3)),
        ]));
        assert_eq!(
            unknown.joined,
            [Joined {
                name: "action".into(),
                keys: vec!["steps/action/a".into(), "steps/action/b".into()],
                names: Vec::new(),
            }]
        );
    }

    /// A map file's features replace the rules' or add to them; keys the dataset lacks or
    /// cannot concatenate are refused with the dataset's keys listed.
    #[test]
    fn a_map_overrides_the_rules_and_is_checked() {
        let all = leaves(&[
            ("action/world_vector", tensor("float32", 3)),
            ("action/rotation_delta", tensor("float32", 3)),
            ("observation/state", tensor("float32", 3)),
            ("observation/note", Leaf::Text),
            (
                "observation/image",
                Leaf::Image {
                    shape: [Some(2), Some(2), Some(3)],
                    dtype: "uint8".into(),
                    format: None,
                },
            ),
        ]);
        let joined = |name: &str, keys: &[&str]| Joined {
            name: name.into(),
            keys: keys.iter().map(|k| format!("steps/{k}")).collect(),
            names: Vec::new(),
        };
        let map = [
            joined("action", &["action/rotation_delta"]),
            joined("task", &["observation/note"]),
        ];
        let mapping = Mapping::of(&all).with(&map, &all).expect("map");
        assert_eq!(mapping.joined, [map[0].clone()]);
        assert_eq!(
            mapping.instruction.map(|i| i.key),
            Some("steps/observation/note".into())
        );
        for (bad, problem) in [
            (
                joined("action", &["action/gripper"]),
                "steps/action/gripper is not a numeric key",
            ),
            (joined("x", &["observation/image"]), "is not a numeric key"),
            (
                joined("task", &["observation/state"]),
                "not a text or integer key",
            ),
        ] {
            let error = Mapping::of(&all).with(&[bad], &all).expect_err(problem);
            assert!(
                error.contains(problem) && error.contains("steps/observation/note"),
                "{error}"
            );
        }
    }
}
