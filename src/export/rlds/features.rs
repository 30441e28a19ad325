//! The two metadata files of a TFDS dataset folder: `features.json` (the feature tree
//! `tensorflow_datasets` rebuilds the decoders from) and `dataset_info.json` (name, version and
//! the train split's `shardLengths`, which readers check exactly). Both derive from the
//! [`DatasetInfo`] and the [`RldsOptions`]; nothing here knows how the episodes were made.

use crate::episode::{Dtype, FeatureKind};
use crate::export::info::DatasetInfo;
use crate::export::rlds::options::RldsOptions;
use serde_json::{Value, json};

const FEATURES_DICT: &str = "tensorflow_datasets.core.features.features_dict.FeaturesDict";
const DATASET: &str = "tensorflow_datasets.core.features.dataset_feature.Dataset";
const TENSOR: &str = "tensorflow_datasets.core.features.tensor_feature.Tensor";
const SCALAR: &str = "tensorflow_datasets.core.features.scalar.Scalar";
const IMAGE: &str = "tensorflow_datasets.core.features.image_feature.Image";
const TEXT: &str = "tensorflow_datasets.core.features.text_feature.Text";

/// The split template TFDS writes (and reads when it is given).
pub const FILEPATH_TEMPLATE: &str = "{DATASET}-{SPLIT}.{FILEFORMAT}-{SHARD_X_OF_Y}";

fn features_dict(features: serde_json::Map<String, Value>, description: &str) -> Value {
    json!({
        "pythonClassName": FEATURES_DICT,
        "featuresDict": {"features": features},
        "description": description,
    })
}

fn tensor(length: usize, description: &str) -> Value {
    json!({
        "pythonClassName": TENSOR,
        "tensor": {"dtype": "float32", "encoding": "none", "shape": {"dimensions": [length.to_string()]}},
        "description": description,
    })
}

fn scalar(dtype: &str, description: &str) -> Value {
    json!({
        "pythonClassName": SCALAR,
        "tensor": {"dtype": dtype, "encoding": "none", "shape": {}},
        "description": description,
    })
}

fn image(shape: [usize; 3], dtype: &str, description: &str) -> Value {
    json!({
        "pythonClassName": IMAGE,
        "image": {
            "dtype": dtype,
            "encodingFormat": "png",
            "shape": {"dimensions": shape.map(|d| d.to_string())},
        },
        "description": description,
    })
}

/// An 8-bit image feature stored in `format` ("png" or "jpeg").
fn image_as(shape: [usize; 3], format: &str, description: &str) -> Value {
    json!({
        "pythonClassName": IMAGE,
        "image": {
            "dtype": "uint8",
            "encodingFormat": format,
            "shape": {"dimensions": shape.map(|d| d.to_string())},
        },
        "description": description,
    })
}

fn text(description: &str) -> Value {
    json!({"pythonClassName": TEXT, "text": {}, "description": description})
}

/// Names of a vector feature's elements, for its description.
fn element_names(info: &DatasetInfo, kind: FeatureKind) -> String {
    info.feature(kind)
        .map(|f| f.names.join(", "))
        .unwrap_or_default()
}

/// The observation features of one step, by RLDS key.
fn observation(info: &DatasetInfo, options: &RldsOptions) -> serde_json::Map<String, Value> {
    let (width, height) = info.image_size();
    let keys = &options.keys;
    let mut observation = serde_json::Map::new();
    for feature in &info.features {
        let (key, node) = match feature.kind {
            FeatureKind::Rgb => (
                &keys.image,
                match options.jpeg_quality {
                    None => image(
                        [height, width, 3],
                        "uint8",
                        "Endoscope RGB image (3-channel PNG).",
                    ),
                    Some(quality) => image_as(
                        [height, width, 3],
                        "jpeg",
                        &format!("Endoscope RGB image (JPEG, quality {quality})."),
                    ),
                },
            ),
            FeatureKind::Depth => (
                &keys.depth,
                image(
                    [height, width, 1],
                    "uint16",
                    "Endoscope depth along the optical axis in millimetres (uint16 PNG; 0 = nothing in range).",
                ),
            ),
            FeatureKind::Mask => (
                &keys.mask,
                image(
                    [height, width, 1],
                    "uint8",
                    "Segmentation mask ids (uint8 PNG); the id table is in surgvla.json.",
                ),
            ),
            FeatureKind::State => (
                &keys.state,
                tensor(
                    feature.shape.iter().product(),
                    &format!(
                        "Robot state: {} (metres, radians).",
                        element_names(info, FeatureKind::State)
                    ),
                ),
            ),
            FeatureKind::EnvironmentState => (
                &keys.environment_state,
                tensor(
                    feature.shape.iter().product(),
                    "Ground-truth object poses, x y z (m) qx qy qz qw per object, zero-padded (privileged).",
                ),
            ),
            FeatureKind::Action | FeatureKind::Other => continue,
        };
        observation.insert(key.clone(), node);
    }
    observation
}

/// `features.json`: the RLDS tree of steps and episode metadata.
pub fn features_json(info: &DatasetInfo, options: &RldsOptions) -> Value {
    let mut step = serde_json::Map::new();
    step.insert(
        "observation".into(),
        features_dict(observation(info, options), "What the robot observed."),
    );
    step.insert(
        "action".into(),
        tensor(
            7,
            &format!(
                "Action: {} (end-effector deltas in metres and radians; gripper absolute, 1 = open, 0 = closed).",
                element_names(info, FeatureKind::Action)
            ),
        ),
    );
    step.insert("language_instruction".into(), text("The task instruction."));
    step.insert("is_first".into(), scalar("bool", "True on the first step."));
    step.insert("is_last".into(), scalar("bool", "True on the last step."));
    step.insert(
        "is_terminal".into(),
        scalar(
            "bool",
            "True on the last step of a successful episode (the task's success state).",
        ),
    );
    step.insert(
        "reward".into(),
        scalar(
            "float32",
            "1.0 on the step after which the task's success predicate holds (the last step of a successful episode), else 0.0.",
        ),
    );
    step.insert("discount".into(), scalar("float32", "Always 1.0."));
    let mut metadata = serde_json::Map::new();
    metadata.insert(
        "file_path".into(),
        text("A stable id of the episode: task id and seed, e.g. T1-1/seed-123."),
    );
    metadata.insert(
        "episode_index".into(),
        scalar("int64", "Position in the dataset, 0-based."),
    );
    metadata.insert(
        "task_id".into(),
        text("The benchmark's task id, e.g. T1-1."),
    );
    metadata.insert("level".into(), scalar("int64", "The task's level, 1..3."));
    metadata.insert(
        "seed".into(),
        scalar("uint64", "The seed that re-creates the episode's scene."),
    );
    metadata.insert(
        "attempts".into(),
        scalar(
            "int64",
            "Expert attempts for this episode including the saved one.",
        ),
    );
    metadata.insert(
        "success".into(),
        scalar("bool", "The task's success predicate held at the end."),
    );
    let mut top = serde_json::Map::new();
    top.insert(
        "steps".into(),
        json!({
            "pythonClassName": DATASET,
            "sequence": {"feature": features_dict(step, "One control step."), "length": "-1"},
            "description": "The episode's control steps.",
        }),
    );
    top.insert(
        "episode_metadata".into(),
        features_dict(metadata, "The episode's provenance."),
    );
    features_dict(top, "")
}

/// `dataset_info.json`: `shard_lengths` holds the episodes of each shard in order and
/// `example_bytes` the sum of the serialized Examples.
pub fn dataset_info_json(
    info: &DatasetInfo,
    options: &RldsOptions,
    shard_lengths: &[u64],
    example_bytes: u64,
) -> Value {
    json!({
        "name": options.name,
        "version": options.version,
        "fileFormat": "tfrecord",
        "description": format!(
            "Surgical robot episodes in RLDS, written by {} (one episode per tf.train.Example). \
             Camera intrinsics, world_from_camera and mask ids are in surgvla.json beside this file; \
             OPENVLA.md in the data directory shows how to fine-tune OpenVLA on it.",
            info.generator
        ),
        "citation": "",
        "releaseNotes": {options.version.clone(): "Written by surgvla."},
        "splits": [{
            "name": super::options::tfds_split(&info.splits),
            "shardLengths": shard_lengths.iter().map(u64::to_string).collect::<Vec<_>>(),
            "numBytes": example_bytes.to_string(),
            "filepathTemplate": FILEPATH_TEMPLATE,
        }],
    })
}

/// Nests `leaf` at `path` in a tree of plain maps.
fn insert_at(tree: &mut serde_json::Map<String, Value>, path: &[String], leaf: Value) {
    match path {
        [] => {}
        [last] => {
            tree.insert(last.clone(), leaf);
        }
        [first, rest @ ..] => {
            let child = tree
                .entry(first.clone())
                .or_insert_with(|| Value::Object(serde_json::Map::new()));
            if let Value::Object(child) = child {
                insert_at(child, rest, leaf);
            }
        }
    }
}

/// A tree of plain maps as nested FeaturesDicts (leaves have a pythonClassName already).
fn as_features_dicts(tree: serde_json::Map<String, Value>) -> serde_json::Map<String, Value> {
    tree.into_iter()
        .map(|(key, value)| match value {
            Value::Object(map) if !map.contains_key("pythonClassName") => {
                (key, features_dict(as_features_dicts(map), ""))
            }
            leaf => (key, leaf),
        })
        .collect()
}

/// `features.json` of a dataset another tool made (its features all
/// [`FeatureKind::Other`]): each feature at its [`crate::export::rlds::rlds_path`], the language instruction and
/// the RLDS flags; `episode_metadata/file_path`.
pub fn foreign_features_json(
    info: &DatasetInfo,
    formats: &std::collections::BTreeMap<String, String>,
) -> Value {
    let mut step = serde_json::Map::new();
    for feature in &info.features {
        let leaf = match feature.dtype {
            Dtype::Image => {
                let mut shape = [0usize; 3];
                for (s, v) in shape.iter_mut().zip(&feature.shape) {
                    *s = *v;
                }
                // A depth map in millimetres, or any 16-bit PNG, is uint16 to TFDS.
                let millimetres = feature.info.get("depth_unit").is_some_and(|u| u == "mm");
                let description = format!("{} (as stored).", feature.name);
                match formats.get(&feature.name).map(String::as_str) {
                    Some("tiff") => shaped_tensor("float32", &shape, &description),
                    Some("png16") => image(shape, "uint16", &description),
                    _ if millimetres => image(shape, "uint16", &description),
                    Some("jpeg") => image_as(shape, "jpeg", &description),
                    _ => image(shape, "uint8", &description),
                }
            }
            Dtype::Float32 | Dtype::Float64 | Dtype::Int64 => {
                // float64 as TFDS declares it; TFRecord stores it as float32 (a note says).
                let dtype = match feature.dtype {
                    Dtype::Int64 => "int64",
                    Dtype::Float64 => "float64",
                    _ => "float32",
                };
                shaped_tensor(dtype, &declared_shape(feature), &feature.name)
            }
            Dtype::String => text(&format!("{} (one text per step).", feature.name)),
        };
        insert_at(
            &mut step,
            &crate::export::rlds::options::rlds_path(&feature.name),
            leaf,
        );
    }
    step.insert("language_instruction".into(), text("The episode's task."));
    for flag in ["is_first", "is_last", "is_terminal"] {
        step.insert(flag.into(), scalar("bool", flag));
    }
    // The input's per-episode values at their own paths; `episode_metadata/file_path` says
    // the episode's index unless the input has one.
    let mut episode = serde_json::Map::new();
    if !crate::export::rlds::record::metadata_taken(info) {
        insert_at(
            &mut episode,
            &["episode_metadata".into(), "file_path".into()],
            text("episode-N, N the episode's index."),
        );
    }
    for field in &info.episode_fields {
        let path: Vec<String> = field.key.split('/').map(String::from).collect();
        insert_at(&mut episode, &path, field_leaf(field));
    }
    let mut top = as_features_dicts(episode);
    top.insert(
        "steps".into(),
        json!({
            "pythonClassName": DATASET,
            "sequence": {"feature": features_dict(as_features_dicts(step), "One step."), "length": "-1"},
            "description": "The episode's steps.",
        }),
    );
    features_dict(top, "")
}

/// The shape to declare for a vector feature: the one another tool's RLDS dataset declared it
/// with (kept in its info when it was flattened), else its own.
fn declared_shape(feature: &crate::episode::FeatureSpec) -> Vec<usize> {
    let elements: usize = feature.shape.iter().product();
    let recorded: Option<Vec<usize>> = (feature.info.get(crate::export::rlds::foreign::SHAPE_KEY))
        .and_then(Value::as_array)
        .and_then(|dims| {
            dims.iter()
                .map(|d| d.as_u64().map(|d| d as usize))
                .collect()
        });
    match recorded {
        Some(dims) if dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)) == Some(elements) => {
            dims
        }
        _ => vec![elements],
    }
}

/// A tensor of `dtype` and `dims`.
fn shaped_tensor(dtype: &str, dims: &[usize], description: &str) -> Value {
    let dims: Vec<String> = dims.iter().map(usize::to_string).collect();
    json!({
        "pythonClassName": TENSOR,
        "tensor": {"dtype": dtype, "encoding": "none", "shape": {"dimensions": dims}},
        "description": description,
    })
}

/// The declaration of another tool's per-episode value: a text, a scalar, or a vector.
fn field_leaf(field: &crate::episode::EpisodeField) -> Value {
    use crate::episode::FieldDtype;
    let description = format!("{} (the input's, per episode).", field.key);
    let dtype = match field.dtype {
        FieldDtype::Text => return text(&description),
        FieldDtype::Int64 => "int64",
        FieldDtype::Float => "float32",
        FieldDtype::Bool => "bool",
    };
    if field.len == 1 {
        return scalar(dtype, &description);
    }
    shaped_tensor(dtype, &[field.len], &description)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{FeatureSet, standard_features};

    fn info(set: FeatureSet) -> DatasetInfo {
        DatasetInfo {
            fps: 5,
            robot_type: "dvrk_psm".into(),
            camera: crate::episode::CameraInfo {
                width_px: 224,
                height_px: 224,
                fx_px: 1.0,
                fy_px: 1.0,
                cx_px: 1.0,
                cy_px: 1.0,
                near_m: 0.01,
                far_m: 1.0,
                world_from_camera: [[0.0; 4]; 4],
            },
            features: standard_features(224, 224, set),
            mask_ids: Vec::new(),
            collection: None,
            generator: "surgvla test".into(),
            tip_workspace: None,
            input: None,
            provenance: Vec::new(),
            splits: Vec::new(),
            notes: Vec::new(),
            omitted: Vec::new(),
            episode_fields: Vec::new(),
            carried_keys: Default::default(),
            history: Vec::new(),
        }
    }

    #[test]
    fn a_flattened_tensor_is_declared_with_the_shape_it_came_with_when_that_fits() {
        let mut feature = crate::episode::FeatureSpec {
            name: "observation.depth_static".into(),
            dtype: Dtype::Float32,
            shape: vec![6],
            names: Vec::new(),
            kind: FeatureKind::Other,
            video: None,
            info: Default::default(),
        };
        assert_eq!(declared_shape(&feature), [6]);
        let key = crate::export::rlds::foreign::SHAPE_KEY;
        feature.info.insert(key.into(), json!([2, 3]));
        assert_eq!(declared_shape(&feature), [2, 3]);
        // A recorded shape that does not hold the values (edited, hostile) is not believed.
        feature.info.insert(key.into(), json!([4, 4]));
        assert_eq!(declared_shape(&feature), [6]);
        feature.info.insert(key.into(), json!([u64::MAX, 2]));
        assert_eq!(declared_shape(&feature), [6]);
    }

    #[test]
    fn the_feature_tree_follows_the_dataset_features_and_key_names() {
        let options = RldsOptions::default();
        let tree = features_json(&info(FeatureSet::default()), &options);
        let step = &tree["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"]
            ["features"];
        let observation = &step["observation"]["featuresDict"]["features"];
        let keys: Vec<&String> = observation.as_object().expect("dict").keys().collect();
        assert_eq!(keys, ["image", "depth", "state", "environment_state"]);
        assert_eq!(observation["image"]["image"]["dtype"], "uint8");
        assert_eq!(
            observation["depth"]["image"]["shape"]["dimensions"],
            json!(["224", "224", "1"])
        );
        assert_eq!(observation["depth"]["image"]["dtype"], "uint16");
        assert_eq!(
            step["action"]["tensor"]["shape"]["dimensions"],
            json!(["7"])
        );
        let lean = FeatureSet {
            depth: false,
            mask: true,
            environment_state: false,
        };
        let mut renamed = RldsOptions::default();
        renamed.keys.image = "agentview_rgb".into();
        let tree = features_json(&info(lean), &renamed);
        let observation = &tree["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"]
            ["features"]["observation"]["featuresDict"]["features"];
        let keys: Vec<&String> = observation.as_object().expect("dict").keys().collect();
        assert_eq!(keys, ["agentview_rgb", "mask", "state"]);
    }

    #[test]
    fn dataset_info_lists_shard_lengths_as_strings() {
        let json = dataset_info_json(
            &info(FeatureSet::default()),
            &RldsOptions::default(),
            &[3, 2],
            1234,
        );
        assert_eq!(json["name"], "surgvla_benchmark");
        assert_eq!(json["version"], "1.0.0");
        assert_eq!(json["splits"][0]["shardLengths"], json!(["3", "2"]));
        assert_eq!(json["splits"][0]["numBytes"], "1234");
    }
}
