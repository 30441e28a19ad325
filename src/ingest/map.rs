//! `--map FILE.toml`: features from topics the preset does not cover (a second instrument's
//! pose, the endoscope's (ECM) pose, a force sensor, any numeric fields), each a float32 vector
//! after the action, synchronised like the preset's own streams. The schema (documented in
//! `docs/ingest.md`):
//!
//! ```toml
//! [[feature]]
//! name = "observation.meta.force"   # the feature's name
//! topic = "/force_sensor/wrench"    # the topic it is read from
//! kind = "sampled"                  # sampled (default: too old and the frame is not written)
//!                                   # or event (its last value holds)
//! values = "fields"                 # pose | joints | fields
//! fields = ["wrench.force.x", "wrench.force.y", "wrench.force.z"]   # values = "fields"
//! count = 6                         # values = "joints": how many positions
//! names = ["fx", "fy", "fz"]        # optional, one per value
//! ```
//!
//! `pose` is [x, y, z, qx, qy, qz, qw] of a `PoseStamped` or `TransformStamped`; `joints` the
//! first `count` positions of a `JointState`; `fields` numbers at dotted paths (`a.b[2]` for an
//! array's element). The file is the user's input: its size is bounded, unknown keys, bad names
//! and clashes with the preset's features are refused by name. The same format maps a
//! dataset's keys for `convert --map` ([`load_keys`]): `keys = [...]` in place of `topic`,
//! `values`, `fields` and `count`.

use crate::export::source::Joined;
use crate::ingest::decode::RosValue;
use crate::ingest::error::IngestError;
use crate::ingest::extract::{joint_positions, pose7};
use crate::ingest::sync::StreamKind;
use serde::Deserialize;
use std::path::Path;

/// The largest map file read.
const MAX_MAP_BYTES: u64 = 1 << 20;
/// The most values one mapped feature may have.
const MAX_VALUES: usize = 1024;

/// How a message becomes a mapped feature's values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Values {
    Pose,
    Joints,
    #[default]
    Fields,
}

/// A mapped stream's role in synchronisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MapKind {
    #[default]
    Sampled,
    Event,
}

/// One `[[feature]]` of a map file.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappedFeature {
    pub name: String,
    /// The recording's topic (`ingest`).
    #[serde(default)]
    pub topic: String,
    /// The dataset's keys, concatenated in order (`convert` of an RLDS dataset another tool
    /// wrote): `steps/action/world_vector`, or without the `steps/`.
    #[serde(default)]
    pub keys: Vec<String>,
    #[serde(default)]
    pub kind: MapKind,
    #[serde(default)]
    pub values: Values,
    #[serde(default)]
    pub fields: Vec<String>,
    #[serde(default)]
    pub count: Option<usize>,
    #[serde(default)]
    pub names: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MapFile {
    #[serde(default)]
    feature: Vec<MappedFeature>,
}

/// The names the preset's own features have (a mapped feature may not take one).
fn reserved(name: &str) -> bool {
    ["observation.state", "action", "instruction.text"].contains(&name)
        || name.starts_with("observation.images.")
}

impl MappedFeature {
    /// How many values a message gives.
    pub fn len(&self) -> usize {
        match self.values {
            Values::Pose => 7,
            Values::Joints => self.count.unwrap_or(0),
            Values::Fields => self.fields.len(),
        }
    }

    /// Whether it gives no value (never, once checked).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn stream_kind(&self) -> StreamKind {
        match self.kind {
            MapKind::Sampled => StreamKind::Sampled,
            MapKind::Event => StreamKind::Event,
        }
    }

    /// One name per value: as given, else the pose's or the fields' own.
    pub fn value_names(&self) -> Vec<String> {
        if !self.names.is_empty() {
            return self.names.clone();
        }
        match self.values {
            Values::Pose => ["x", "y", "z", "qx", "qy", "qz", "qw"]
                .map(String::from)
                .to_vec(),
            Values::Joints => (0..self.len()).map(|i| format!("joint_{i}")).collect(),
            Values::Fields => self.fields.clone(),
        }
    }

    /// The feature's values from a message of its topic.
    pub fn extract(&self, message: &RosValue) -> Result<Vec<f32>, String> {
        let values: Vec<f64> = match self.values {
            Values::Pose => pose7(message)?.to_vec(),
            Values::Joints => {
                let positions = joint_positions(message)?;
                let n = self.len();
                if positions.len() < n {
                    return Err(format!(
                        "holds {} positions where the map asks for {n}",
                        positions.len()
                    ));
                }
                positions[..n].to_vec()
            }
            Values::Fields => (self.fields.iter())
                .map(|path| {
                    number_at(message, path).ok_or_else(|| format!("has no number at {path}"))
                })
                .collect::<Result<_, _>>()?,
        };
        Ok(values.into_iter().map(|v| v as f32).collect())
    }

    fn check(&self) -> Result<(), String> {
        let valid_name = !self.name.is_empty()
            && (self.name.chars()).all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
        if !valid_name {
            return Err("a feature name is letters, digits, '.', '_' and '-'".into());
        }
        if reserved(&self.name) {
            return Err("the preset writes a feature of this name".into());
        }
        if !self.keys.is_empty() {
            return Err("keys = [...] names a dataset's keys (convert --map); a recording's feature names its topic".into());
        }
        if !self.topic.starts_with('/') {
            return Err(format!("topic {:?} must start with /", self.topic));
        }
        match self.values {
            Values::Fields if self.fields.is_empty() => {
                return Err("values = \"fields\" needs fields = [...]".into());
            }
            Values::Joints if !matches!(self.count, Some(1..)) => {
                return Err("values = \"joints\" needs count = N (N >= 1)".into());
            }
            Values::Pose | Values::Joints if !self.fields.is_empty() => {
                return Err("fields are for values = \"fields\"".into());
            }
            _ => {}
        }
        if self.len() > MAX_VALUES {
            return Err(format!("more than {MAX_VALUES} values"));
        }
        if !self.names.is_empty() && self.names.len() != self.len() {
            return Err(format!(
                "{} names for {} values",
                self.names.len(),
                self.len()
            ));
        }
        Ok(())
    }
}

/// The number at a dotted path of fields, `name[i]` taking an array's element.
fn number_at(message: &RosValue, path: &str) -> Option<f64> {
    let mut value = message;
    let mut segments = path.split('.').peekable();
    while let Some(segment) = segments.next() {
        let (name, index) = match segment.split_once('[') {
            Some((name, rest)) => (name, Some(rest.strip_suffix(']')?.parse::<usize>().ok()?)),
            None => (segment, None),
        };
        value = value.field(name)?;
        match (index, value) {
            (None, _) => {}
            (Some(i), RosValue::Array(items)) => value = items.get(i)?,
            // A byte array's element is a number, and nothing is below it.
            (Some(i), RosValue::Bytes(bytes)) if segments.peek().is_none() => {
                return bytes.get(i).map(|&b| f64::from(b));
            }
            (Some(_), _) => return None,
        }
    }
    value.as_f64()
}

/// Reads a map file's text: its size is bounded, any problem is the user's (exit 2), named
/// with the file.
fn read(path: &Path) -> Result<String, IngestError> {
    let usage =
        |problem: String| IngestError::Usage(format!("--map {}: {problem}", path.display()));
    let metadata = std::fs::metadata(path).map_err(|e| usage(e.to_string()))?;
    if !metadata.is_file() {
        return Err(usage("not a file".into()));
    }
    if metadata.len() > MAX_MAP_BYTES {
        return Err(usage(format!("larger than {MAX_MAP_BYTES} bytes")));
    }
    crate::files::read_regular_to_string(path).map_err(|e| usage(e.to_string()))
}

/// Reads and checks a map file of a recording (`ingest --map`): any problem is the user's
/// (exit 2), named with the file and the feature.
pub fn load(path: &Path) -> Result<Vec<MappedFeature>, IngestError> {
    let usage =
        |problem: String| IngestError::Usage(format!("--map {}: {problem}", path.display()));
    parse(&read(path)?).map_err(usage)
}

/// Reads and checks a map file of a dataset (`convert --map`): each feature made of the
/// input's keys, `task` naming where the instruction is.
pub fn load_keys(path: &Path) -> Result<Vec<Joined>, IngestError> {
    let usage =
        |problem: String| IngestError::Usage(format!("--map {}: {problem}", path.display()));
    parse_keys(&read(path)?).map_err(usage)
}

/// A map file's features, checked.
pub fn parse(text: &str) -> Result<Vec<MappedFeature>, String> {
    let file: MapFile = toml::from_str(text).map_err(|e| e.message().to_string())?;
    for (i, feature) in file.feature.iter().enumerate() {
        feature
            .check()
            .map_err(|problem| format!("feature {:?}: {problem}", feature.name))?;
        if file.feature[..i].iter().any(|f| f.name == feature.name) {
            return Err(format!("feature {:?} is given twice", feature.name));
        }
    }
    Ok(file.feature)
}

/// A dataset map's features: names as a recording's map checks them (any name: a dataset has
/// no preset), keys and no topic.
pub fn parse_keys(text: &str) -> Result<Vec<Joined>, String> {
    let file: MapFile = toml::from_str(text).map_err(|e| e.message().to_string())?;
    let mut joined: Vec<Joined> = Vec::new();
    for feature in file.feature {
        let problem = |p: &str| format!("feature {:?}: {p}", feature.name);
        let valid_name = !feature.name.is_empty()
            && (feature.name.chars()).all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
        if !valid_name {
            return Err(problem(
                "a feature name is letters, digits, '.', '_' and '-'",
            ));
        }
        if !feature.topic.is_empty() || !feature.fields.is_empty() || feature.count.is_some() {
            return Err(problem(
                "topic, values, fields and count are for recordings (ingest --map); a dataset's feature names its keys = [...]",
            ));
        }
        if feature.keys.is_empty() {
            return Err(problem("keys = [...] names the dataset keys it is made of"));
        }
        if joined.iter().any(|j| j.name == feature.name) {
            return Err(format!("feature {:?} is given twice", feature.name));
        }
        let keys = (feature.keys.iter())
            .map(|k| match k.starts_with("steps/") {
                true => k.clone(),
                false => format!("steps/{k}"),
            })
            .collect();
        joined.push(Joined {
            name: feature.name,
            keys,
            names: feature.names,
        });
    }
    Ok(joined)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::fixtures::message;

    const EXAMPLE: &str = r#"
[[feature]]
name = "observation.meta.ecm_pose"
topic = "/ECM/measured_cp"
values = "pose"

[[feature]]
name = "observation.meta.force"
topic = "/force/wrench"
kind = "event"
values = "fields"
fields = ["wrench.force.x", "wrench.torque[1]"]
names = ["fx", "ty"]

[[feature]]
name = "observation.meta.ecm_joints"
topic = "/ECM/measured_js"
values = "joints"
count = 2
"#;

    #[test]
    fn a_map_reads_poses_joints_and_fields() {
        let features = parse(EXAMPLE).expect("parse");
        assert_eq!(features.len(), 3);
        assert_eq!(features[0].value_names()[6], "qw");
        assert_eq!(features[1].value_names(), ["fx", "ty"]);
        assert_eq!(features[1].stream_kind(), StreamKind::Event);
        assert_eq!(features[2].value_names(), ["joint_0", "joint_1"]);
        let wrench = message(vec![(
            "wrench",
            message(vec![
                ("force", message(vec![("x", RosValue::Float(1.5))])),
                (
                    "torque",
                    RosValue::Array(vec![RosValue::Float(0.0), RosValue::Int(-2)]),
                ),
            ]),
        )]);
        assert_eq!(features[1].extract(&wrench), Ok(vec![1.5, -2.0]));
        let joints = message(vec![(
            "position",
            RosValue::Array(vec![
                RosValue::Float(0.25),
                RosValue::Float(0.5),
                RosValue::Float(1.0),
            ]),
        )]);
        assert_eq!(features[2].extract(&joints), Ok(vec![0.25, 0.5]));
        let short = message(vec![(
            "position",
            RosValue::Array(vec![RosValue::Float(0.25)]),
        )]);
        assert!(
            features[2]
                .extract(&short)
                .is_err_and(|e| e.contains("asks for 2"))
        );
        assert!(
            features[1]
                .extract(&joints)
                .is_err_and(|e| e.contains("wrench.force.x"))
        );
    }

    #[test]
    fn a_bad_map_is_refused_by_name() {
        for (text, problem) in [
            (
                "[[feature]]\nname = \"action\"\ntopic = \"/a\"\nvalues = \"pose\"",
                "the preset writes",
            ),
            (
                "[[feature]]\nname = \"a b\"\ntopic = \"/a\"\nvalues = \"pose\"",
                "letters, digits",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"a\"\nvalues = \"pose\"",
                "must start with /",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"fields\"",
                "needs fields",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"joints\"",
                "needs count",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"pose\"\nnames = [\"a\"]",
                "1 names for 7",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"pose\"\ncolour = 1",
                "unknown field",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"speed\"",
                "unknown variant",
            ),
            (
                "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nvalues = \"pose\"\n[[feature]]\nname = \"x\"\ntopic = \"/b\"\nvalues = \"pose\"",
                "given twice",
            ),
        ] {
            let error = parse(text).expect_err(problem);
            assert!(error.contains(problem), "{problem}: {error}");
        }
    }
}
