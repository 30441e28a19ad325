//! How a dataset's episodes were made: the [`Collection`] record a dataset's surgvla metadata
//! holds (`meta/surgvla.json`'s `collection`, or the same key in a zarr's or a point-cloud
//! dataset's attributes), with the [`Shard`] of a run it holds ([`RecordedShard`]).
//!
//! What surgvla writes is typed: a collection run's [`RunRecord`] and an evaluation's
//! [`EvaluationRecord`]. What it reads back may come from an older surgvla or be edited by
//! another tool, so a `Collection` keeps the record as it was read, every key in its order (a
//! merge writes it back byte for byte, with only its shard changed), and answers typed
//! questions about it: a value that is missing or of another type reads as unknown, never as
//! an error.

use crate::episode::GripperEncoding;
use serde::Serialize;
use serde_json::{Map, Value};
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// One part of a collection split across machines: `index` of `count` (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Default for Shard {
    fn default() -> Self {
        Shard { index: 0, count: 1 }
    }
}

/// A shard written other than "I/N" with I < N.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "shard '{0}': expected I/N with 0 <= I < N, e.g. 0/4 (Slurm: $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)"
)]
pub struct BadShard(pub String);

impl FromStr for Shard {
    type Err = BadShard;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = || BadShard(text.to_string());
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let index: u32 = i.trim().parse().map_err(|_| bad())?;
        let count: u32 = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// This shard's contiguous part of `0..total`.
    pub fn range(&self, total: usize) -> std::ops::Range<usize> {
        let part = |i: u32| (total as u128 * u128::from(i) / u128::from(self.count)) as usize;
        part(self.index)..part(self.index + 1)
    }
}

/// The collection key a shard records itself under.
pub const SHARD_KEY: &str = "shard";

/// Which part of a run a dataset holds, as its collection records it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RecordedShard {
    /// One shard "I/N" ("0/1": the whole run).
    Part(Shard),
    /// Some shards of a run merged without the rest: "merged 0/3,2/3".
    Merged(Vec<Shard>),
}

impl RecordedShard {
    /// The shard, when this is one shard.
    pub fn part(&self) -> Option<Shard> {
        match self {
            RecordedShard::Part(shard) => Some(*shard),
            RecordedShard::Merged(_) => None,
        }
    }

    /// The record of `shards` merged (in the order given): "0/1" again when they are all N of
    /// N in order, else the list.
    pub fn merged(shards: &[Shard]) -> RecordedShard {
        let complete = shards
            .iter()
            .enumerate()
            .all(|(k, s)| s.index as usize == k && s.count as usize == shards.len());
        if complete {
            RecordedShard::Part(Shard::default())
        } else {
            RecordedShard::Merged(shards.to_vec())
        }
    }
}

impl fmt::Display for RecordedShard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RecordedShard::Part(shard) => write!(f, "{shard}"),
            RecordedShard::Merged(shards) => {
                let list: Vec<String> = shards.iter().map(ToString::to_string).collect();
                write!(f, "merged {}", list.join(","))
            }
        }
    }
}

impl FromStr for RecordedShard {
    type Err = ();

    fn from_str(text: &str) -> Result<Self, ()> {
        match text.strip_prefix("merged ") {
            Some(list) => list
                .split(',')
                .map(|s| s.parse().map_err(|_| ()))
                .collect::<Result<Vec<Shard>, ()>>()
                .map(RecordedShard::Merged),
            None => text.parse().map(RecordedShard::Part).map_err(|_| ()),
        }
    }
}

impl Serialize for RecordedShard {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// What `surgvla collect` records about its run, in the order it is written.
#[derive(Clone, Debug, Serialize)]
pub struct RunRecord {
    pub seed: u64,
    /// Task codes ("T1-1", ...), in collection order.
    pub tasks: Vec<String>,
    pub episodes_per_task: u64,
    pub shard: RecordedShard,
    pub gripper_encoding: GripperEncoding,
    pub distractors: usize,
    /// The instruction choice: "canonical", "paraphrase" or "mixed".
    pub instructions: String,
    pub spawn_scale: f64,
    pub randomize_appearance: bool,
    /// With `randomize_appearance`: the ranges drawn from, by dimension of the evaluation's
    /// perturbation suites (`held_out_by` names the file whose levels lie outside them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub appearance_ranges: Option<Value>,
    /// "builtin", or "custom" when plans were loaded from files.
    pub policies: String,
    /// The success rules the episodes were judged by (`crate::task::success::RULE_SET`).
    pub success_rules: String,
    /// Task name -> CRC-32C of its custom plan, when plans are custom.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub custom_plans: Option<BTreeMap<String, String>>,
}

/// What an evaluation records in a failed trial's recording.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct EvaluationRecord {
    /// Always true: the episode is a policy's trial, not an expert's demonstration.
    pub evaluation: bool,
    pub seed: u64,
}

/// A dataset's collection record, as read (every key, in order) or as written from a
/// [`RunRecord`] or [`EvaluationRecord`].
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Collection(Map<String, Value>);

impl Collection {
    /// The record of `record` (a [`RunRecord`] or [`EvaluationRecord`]).
    pub fn of(record: &impl Serialize) -> Collection {
        match serde_json::to_value(record) {
            Ok(Value::Object(fields)) => Collection(fields),
            _ => Collection::default(),
        }
    }

    /// The collection of a dataset's metadata value; None when it has none (or not an object).
    pub fn from_json(value: &Value) -> Option<Collection> {
        value.as_object().map(|fields| Collection(fields.clone()))
    }

    /// As JSON, every key in its order.
    pub fn to_json(&self) -> Value {
        Value::Object(self.0.clone())
    }

    /// Every recorded option in order.
    pub fn entries(&self) -> impl Iterator<Item = (&str, &Value)> {
        self.0.iter().map(|(key, value)| (key.as_str(), value))
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The shard it records; None when it records none (or one that does not parse).
    pub fn shard(&self) -> Option<RecordedShard> {
        self.0.get(SHARD_KEY)?.as_str()?.parse().ok()
    }

    /// The shard's text as recorded, parsed or not (for messages).
    pub fn shard_text(&self) -> Option<&str> {
        self.0.get(SHARD_KEY)?.as_str()
    }

    /// Records `shard` (in the place of the one recorded, else last).
    pub fn set_shard(&mut self, shard: &RecordedShard) {
        self.0
            .insert(SHARD_KEY.into(), Value::from(shard.to_string()));
    }

    pub fn seed(&self) -> Option<u64> {
        self.0.get("seed")?.as_u64()
    }

    /// The gripper encoding of its actions; None when not recorded. Any name but "pulse" is
    /// the default, continuous encoding (the one every other tool's data uses).
    pub fn gripper_encoding(&self) -> Option<GripperEncoding> {
        match self.0.get("gripper_encoding")?.as_str()? {
            "pulse" => Some(GripperEncoding::Pulse),
            _ => Some(GripperEncoding::Continuous),
        }
    }

    /// The instruction choice ("canonical", "paraphrase", "mixed").
    pub fn instructions(&self) -> Option<&str> {
        self.0.get("instructions")?.as_str()
    }

    pub fn distractors(&self) -> Option<usize> {
        usize::try_from(self.0.get("distractors")?.as_u64()?).ok()
    }

    pub fn spawn_scale(&self) -> Option<f64> {
        self.0.get("spawn_scale")?.as_f64()
    }

    /// Whether appearance was randomized (false when not recorded).
    pub fn randomize_appearance(&self) -> bool {
        self.0.get("randomize_appearance") == Some(&Value::Bool(true))
    }

    /// The success rules its episodes were judged by.
    pub fn success_rules(&self) -> Option<&str> {
        self.0.get("success_rules")?.as_str()
    }

    /// The options whose values differ between `self` and `other`, the shard aside, in name
    /// order: (name, `self`'s value, `other`'s value), `Value::Null` where one lacks it.
    pub fn differences(&self, other: &Collection) -> Vec<(String, Value, Value)> {
        let names: std::collections::BTreeSet<&String> =
            self.0.keys().chain(other.0.keys()).collect();
        names
            .into_iter()
            .filter(|name| *name != SHARD_KEY)
            .filter_map(|name| {
                let (a, b) = (self.0.get(name), other.0.get(name));
                (a != b).then(|| {
                    let value = |v: Option<&Value>| v.cloned().unwrap_or(Value::Null);
                    (name.clone(), value(a), value(b))
                })
            })
            .collect()
    }
}

impl fmt::Display for Collection {
    /// Compact JSON.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.to_json())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run() -> RunRecord {
        RunRecord {
            seed: 7,
            tasks: vec!["T1-1".into()],
            episodes_per_task: 2,
            shard: RecordedShard::Part(Shard { index: 1, count: 2 }),
            gripper_encoding: GripperEncoding::Pulse,
            distractors: 1,
            instructions: "mixed".into(),
            spawn_scale: 1.5,
            randomize_appearance: true,
            appearance_ranges: None,
            policies: "builtin".into(),
            success_rules: "rules-v1".into(),
            custom_plans: None,
        }
    }

    #[test]
    fn a_run_reads_back_typed_in_its_key_order() {
        let collection = Collection::of(&run());
        let keys: Vec<&str> = collection.entries().map(|(k, _)| k).collect();
        assert_eq!(keys[..4], ["seed", "tasks", "episodes_per_task", "shard"]);
        assert!(!keys.contains(&"custom_plans"));
        assert_eq!(collection.seed(), Some(7));
        assert_eq!(collection.shard_text(), Some("1/2"));
        assert_eq!(collection.gripper_encoding(), Some(GripperEncoding::Pulse));
        assert_eq!(collection.instructions(), Some("mixed"));
        assert_eq!(collection.distractors(), Some(1));
        assert_eq!(collection.spawn_scale(), Some(1.5));
        assert!(collection.randomize_appearance());
        assert_eq!(collection.success_rules(), Some("rules-v1"));
    }

    #[test]
    fn setting_the_shard_keeps_its_place_and_every_other_byte() {
        let text = r#"{"z":1,"shard":"0/2","a":[1.25,"x"]}"#;
        let value: Value = serde_json::from_str(text).expect("json");
        let mut collection = Collection::from_json(&value).expect("an object");
        assert_eq!(collection.to_string(), text);
        collection.set_shard(&RecordedShard::merged(&[
            Shard { index: 0, count: 3 },
            Shard { index: 2, count: 3 },
        ]));
        assert_eq!(
            collection.to_string(),
            r#"{"z":1,"shard":"merged 0/3,2/3","a":[1.25,"x"]}"#
        );
        assert_eq!(
            collection.shard(),
            Some(RecordedShard::Merged(vec![
                Shard { index: 0, count: 3 },
                Shard { index: 2, count: 3 }
            ]))
        );
    }

    #[test]
    fn all_shards_merged_are_the_whole_run_again() {
        let all = [Shard { index: 0, count: 2 }, Shard { index: 1, count: 2 }];
        assert_eq!(RecordedShard::merged(&all).to_string(), "0/1");
        assert_eq!(RecordedShard::merged(&all[1..]).to_string(), "merged 1/2");
    }

    #[test]
    fn foreign_values_read_as_unknown() {
        let value = serde_json::json!({"seed": "seven", "shard": "1 of 2", "gripper_encoding": 3});
        let collection = Collection::from_json(&value).expect("an object");
        assert_eq!(collection.seed(), None);
        assert_eq!(collection.shard(), None);
        assert_eq!(collection.shard_text(), Some("1 of 2"));
        assert_eq!(collection.gripper_encoding(), None, "not a name");
        assert!(!collection.randomize_appearance());
        let other = serde_json::json!({"gripper_encoding": "binary"});
        let other = Collection::from_json(&other).expect("an object");
        assert_eq!(other.gripper_encoding(), Some(GripperEncoding::Continuous));
        assert!(Collection::from_json(&serde_json::json!("text")).is_none());
        assert!(Collection::from_json(&Value::Null).is_none());
    }

    #[test]
    fn differences_name_every_option_but_the_shard() {
        let a = Collection::from_json(&serde_json::json!({"seed": 1, "shard": "0/2", "x": 1}))
            .expect("a");
        let b = Collection::from_json(&serde_json::json!({"seed": 2, "shard": "1/2"})).expect("b");
        let differ = a.differences(&b);
        let names: Vec<&str> = differ.iter().map(|(n, _, _)| n.as_str()).collect();
        assert_eq!(names, ["seed", "x"]);
        assert_eq!(differ[1].2, Value::Null);
    }
}
