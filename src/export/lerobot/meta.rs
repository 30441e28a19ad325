//! LeRobot's `meta/info.json`, typed ([`InfoJson`], each feature a [`FeatureJson`]), and v2.1's
//! task lines ([`TaskLine`]), for the writer, the reader, the checks, detection and merge alike
//! (episode rows are [`super::table::EpisodeRow`]).
//!
//! Read leniently, since the datasets are often another tool's: every field is optional, a
//! value of the wrong type reads as absent (the checks report it through the JSON Schema and
//! their own findings, rather than stopping at the first), and keys this model does not name are
//! kept (`other`). Written by our writer byte for byte as before: the keys in the order declared
//! here, then any unknown ones. v2.1's `total_videos` and `total_chunks` stand where v3.0 has
//! `data_files_size_in_mb` and `video_files_size_in_mb` (the writer once made v2.1's file by
//! removing those two keys from v3.0's, which moved the last two keys into their places).

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::{Map, Number, Value};
use std::collections::BTreeMap;

/// A field that reads as `None` when absent, null or of another type.
fn lenient<'de, D: Deserializer<'de>, T: DeserializeOwned>(
    deserializer: D,
) -> Result<Option<T>, D::Error> {
    let value = Value::deserialize(deserializer)?;
    Ok(serde_json::from_value(value).ok())
}

/// `meta/info.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InfoJson {
    #[serde(default, deserialize_with = "lenient")]
    pub codebase_version: Option<String>,
    #[serde(default, deserialize_with = "lenient")]
    pub robot_type: Option<String>,
    #[serde(default, deserialize_with = "lenient")]
    pub total_episodes: Option<u64>,
    #[serde(default, deserialize_with = "lenient")]
    pub total_frames: Option<u64>,
    #[serde(default, deserialize_with = "lenient")]
    pub total_tasks: Option<u64>,
    #[serde(default, deserialize_with = "lenient")]
    pub chunks_size: Option<u64>,
    /// v3.0 only.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub data_files_size_in_mb: Option<u64>,
    /// v2.1 only.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub total_videos: Option<u64>,
    /// v3.0 only.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub video_files_size_in_mb: Option<u64>,
    /// v2.1 only.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub total_chunks: Option<u64>,
    /// Frames per second (a number; lerobot writes an integer).
    #[serde(default, deserialize_with = "lenient")]
    pub fps: Option<Number>,
    /// Split name -> "from:to" episode range.
    #[serde(default, deserialize_with = "lenient")]
    pub splits: Option<BTreeMap<String, String>>,
    #[serde(default, deserialize_with = "lenient")]
    pub data_path: Option<String>,
    #[serde(default, deserialize_with = "lenient")]
    pub video_path: Option<String>,
    /// Feature name -> feature, in the file's order.
    #[serde(default, deserialize_with = "lenient")]
    pub features: Option<FeaturesJson>,
    /// Keys this model does not name, kept as they were.
    #[serde(flatten)]
    pub other: Map<String, Value>,
}

/// Features by name, in order.
pub type FeaturesJson = serde_json::Map<String, Value>;

/// One entry of `features` (read from the JSON value with [`FeatureJson::of`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FeatureJson {
    #[serde(default, deserialize_with = "lenient")]
    pub dtype: Option<String>,
    #[serde(default, deserialize_with = "lenient")]
    pub shape: Option<Vec<usize>>,
    #[serde(default)]
    pub names: Value,
    /// Image features: `is_depth_map` / `depth_unit`; video: `video.codec` and the others.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub info: Option<Map<String, Value>>,
    /// Keys this model does not name, kept as they were.
    #[serde(flatten)]
    pub other: Map<String, Value>,
}

impl FeatureJson {
    /// The feature `value` describes, leniently (a value that is not an object has no field).
    pub fn of(value: &Value) -> FeatureJson {
        serde_json::from_value(value.clone()).unwrap_or_default()
    }

    /// The declared shape (empty when absent or malformed).
    pub fn shape(&self) -> &[usize] {
        self.shape.as_deref().unwrap_or_default()
    }

    /// The declared dtype ("" when absent).
    pub fn dtype(&self) -> &str {
        self.dtype.as_deref().unwrap_or_default()
    }

    /// A video feature's codec as info.json names it.
    pub fn video_codec(&self) -> Option<&str> {
        self.info.as_ref()?.get("video.codec")?.as_str()
    }
}

/// One line of v2.1's `meta/tasks.jsonl` (v3.0 keeps the same columns in
/// `meta/tasks.parquet`), read leniently.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TaskLine {
    #[serde(default, deserialize_with = "lenient")]
    pub task_index: Option<i64>,
    #[serde(default, deserialize_with = "lenient")]
    pub task: Option<String>,
}

impl TaskLine {
    /// The line `text` holds (every field absent when it is not a JSON object).
    pub fn of(text: &str) -> TaskLine {
        serde_json::from_str(text).unwrap_or_default()
    }
}

impl InfoJson {
    /// Reads `meta/info.json`'s text leniently: only text that is not a JSON object fails.
    pub fn parse(bytes: &[u8]) -> Result<InfoJson, serde_json::Error> {
        serde_json::from_slice(bytes)
    }

    /// Whether the layout is v2.1 (one file per episode, JSON-lines metadata).
    pub fn is_v21(&self) -> bool {
        self.codebase_version.as_deref() == Some("v2.1")
    }

    /// Frames per second as a float, when it is a positive number.
    pub fn fps_hz(&self) -> Option<f64> {
        self.fps.as_ref()?.as_f64().filter(|f| *f > 0.0)
    }

    /// The features, each read leniently, in the file's order.
    pub fn feature_list(&self) -> Vec<(String, FeatureJson)> {
        self.features
            .iter()
            .flatten()
            .map(|(name, value)| (name.clone(), FeatureJson::of(value)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrong_types_read_as_absent_and_unknown_keys_stay() {
        let info = InfoJson::parse(
            br#"{"codebase_version": 3, "fps": "fast", "chunks_size": 1000, "features": {"a": {"dtype": "float32", "shape": [2], "names": null, "extra": 1}}, "custom": [1]}"#,
        )
        .unwrap();
        assert_eq!(info.codebase_version, None);
        assert_eq!(info.fps_hz(), None);
        assert_eq!(info.chunks_size, Some(1000));
        assert_eq!(info.other["custom"], serde_json::json!([1]));
        let (name, feature) = &info.feature_list()[0];
        assert_eq!(
            (name.as_str(), feature.dtype(), feature.shape()),
            ("a", "float32", &[2][..])
        );
        assert_eq!(feature.other["extra"], 1);
        assert!(InfoJson::parse(b"[1, 2]").is_err());
    }

    #[test]
    fn written_keys_keep_their_order() {
        let info = InfoJson {
            codebase_version: Some("v2.1".into()),
            total_chunks: Some(1),
            ..InfoJson::default()
        };
        let text = serde_json::to_string(&info).unwrap();
        assert!(
            text.starts_with(r#"{"codebase_version":"v2.1","robot_type":null"#),
            "{text}"
        );
        assert!(
            text.contains(r#""chunks_size":null,"total_chunks":1,"fps""#),
            "{text}"
        );
        assert!(!text.contains("data_files_size_in_mb"), "{text}");
    }
}
