//! LeRobot's `meta/info.json`, typed ([`InfoJson`], each feature a [`FeatureJson`]), its
//! statistics (`meta/stats.json` and each episode's, [`StatsJson`]), and v2.1's task lines
//! ([`TaskLine`]), for the writer, the reader, the checks, detection and merge alike (episode
//! rows are [`super::table::EpisodeRow`] when written, [`super::table::StoredEpisode`] when read).
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

/// Statistics by feature name, in order: `meta/stats.json`, an episode's `stats` in v2.1's
/// `episodes_stats.jsonl`, and (flattened to `stats/<feature>/<stat>` columns) v3.0's episodes
/// table.
pub type StatsJson = indexmap::IndexMap<String, FeatureStatsJson>;

/// One statistic's numbers, nested as lerobot writes them: a list per element for vectors
/// (`[d]`), (C, 1, 1) lists for images, `[n]` for the count. Numbers keep their JSON spelling
/// (an integer count stays an integer); a non-finite value is written as null.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum StatValue {
    Null,
    Number(Number),
    List(Vec<StatValue>),
}

/// Read by what the JSON holds, without trying each variant in turn (an episodes table holds
/// thousands of these).
impl<'de> Deserialize<'de> for StatValue {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = StatValue;

            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number, null, or a list of them")
            }

            fn visit_unit<E>(self) -> Result<StatValue, E> {
                Ok(StatValue::Null)
            }

            fn visit_none<E>(self) -> Result<StatValue, E> {
                Ok(StatValue::Null)
            }

            fn visit_u64<E>(self, v: u64) -> Result<StatValue, E> {
                Ok(StatValue::Number(v.into()))
            }

            fn visit_i64<E>(self, v: i64) -> Result<StatValue, E> {
                Ok(StatValue::Number(v.into()))
            }

            fn visit_f64<E>(self, v: f64) -> Result<StatValue, E> {
                Ok(StatValue::number(v))
            }

            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<StatValue, A::Error> {
                let mut items = Vec::new();
                while let Some(item) = seq.next_element::<StatValue>()? {
                    items.push(item);
                }
                Ok(StatValue::List(items))
            }
        }
        d.deserialize_any(Visitor)
    }
}

impl StatValue {
    /// A list of numbers.
    pub fn list(values: impl IntoIterator<Item = f64>) -> StatValue {
        StatValue::List(values.into_iter().map(StatValue::number).collect())
    }

    /// One number (null when not finite, as `serde_json::json!` writes it).
    pub fn number(value: f64) -> StatValue {
        Number::from_f64(value).map_or(StatValue::Null, StatValue::Number)
    }

    /// Depth of nesting: 0 for a number, 1 for `[d]`, 3 for (C, 1, 1).
    pub fn depth(&self) -> usize {
        match self {
            StatValue::List(items) => 1 + items.first().map_or(0, StatValue::depth),
            _ => 0,
        }
    }

    /// The numbers in order, at any depth (null and non-numbers skipped).
    pub fn flat(&self) -> Vec<f64> {
        let mut out = Vec::new();
        self.flatten_into(&mut out);
        out
    }

    fn flatten_into(&self, out: &mut Vec<f64>) {
        match self {
            StatValue::Null => {}
            StatValue::Number(n) => out.extend(n.as_f64()),
            StatValue::List(items) => items.iter().for_each(|i| i.flatten_into(out)),
        }
    }

    /// The outer list's items (none for a number).
    pub fn items(&self) -> &[StatValue] {
        match self {
            StatValue::List(items) => items,
            _ => &[],
        }
    }

    /// The outer list's length, or None when this is not a list.
    pub fn list_len(&self) -> Option<usize> {
        match self {
            StatValue::List(items) => Some(items.len()),
            _ => None,
        }
    }

    /// Element `i` of a list of numbers (None when absent or not a number).
    pub fn element(&self, i: usize) -> Option<f64> {
        match self.items().get(i)? {
            StatValue::Number(n) => n.as_f64(),
            _ => None,
        }
    }
}

/// One feature's statistics, in lerobot's order (min, max, mean, std, count, q01..q99), each
/// read leniently; other statistics are kept after them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FeatureStatsJson {
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub min: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub max: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub mean: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub std: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub count: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub q01: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub q10: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub q50: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub q90: Option<StatValue>,
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub q99: Option<StatValue>,
    /// Statistics this model does not name, kept as they were.
    #[serde(flatten)]
    pub other: Map<String, Value>,
}

impl FeatureStatsJson {
    /// The statistics `value` holds, leniently (nothing when it is not an object): what
    /// deserializing it gives, each key taken as it is (the derived reader buffers a whole
    /// object for the statistics it does not name, and every episode's row passes here).
    pub fn from_value(value: Value) -> FeatureStatsJson {
        let Value::Object(entries) = value else {
            return FeatureStatsJson::default();
        };
        let mut stats = FeatureStatsJson::default();
        for (key, value) in entries {
            match stats.slot(&key) {
                Some(slot) => *slot = serde_json::from_value(value).ok(),
                None => {
                    stats.other.insert(key, value);
                }
            }
        }
        stats
    }

    /// Statistics as `stated`, as [`FeatureStatsJson::from_value`] reads them from
    /// `stated.to_json()`, without the JSON between.
    pub fn from_stated(stated: &crate::export::stats::Stated) -> FeatureStatsJson {
        let number = |v: f64| Number::from_f64(v).map_or(StatValue::Null, StatValue::Number);
        let list = |values: &[f64]| {
            StatValue::List(
                (values.iter())
                    .map(|&v| match stated.image {
                        true => StatValue::List(vec![StatValue::List(vec![number(v)])]),
                        false => number(v),
                    })
                    .collect(),
            )
        };
        let mut stats = FeatureStatsJson::default();
        let moments = crate::export::stats::MOMENTS.iter().zip(&stated.moments);
        for (name, values) in moments.chain(stated.quantiles.iter().map(|(n, v)| (n, v))) {
            stats.set(name, list(values));
        }
        let count = StatValue::Number(Number::from(stated.count));
        stats.count = Some(StatValue::List(vec![count]));
        stats
    }

    /// The named statistics present, in order (the unknown ones are not listed).
    pub fn named(&self) -> Vec<(&'static str, &StatValue)> {
        let all = [
            ("min", &self.min),
            ("max", &self.max),
            ("mean", &self.mean),
            ("std", &self.std),
            ("count", &self.count),
            ("q01", &self.q01),
            ("q10", &self.q10),
            ("q50", &self.q50),
            ("q90", &self.q90),
            ("q99", &self.q99),
        ];
        all.into_iter()
            .filter_map(|(name, value)| Some((name, value.as_ref()?)))
            .collect()
    }

    /// The statistic called `name`, if named here and present.
    pub fn get(&self, name: &str) -> Option<&StatValue> {
        match name {
            "min" => self.min.as_ref(),
            "max" => self.max.as_ref(),
            "mean" => self.mean.as_ref(),
            "std" => self.std.as_ref(),
            "count" => self.count.as_ref(),
            "q01" => self.q01.as_ref(),
            "q10" => self.q10.as_ref(),
            "q50" => self.q50.as_ref(),
            "q90" => self.q90.as_ref(),
            "q99" => self.q99.as_ref(),
            _ => None,
        }
    }

    /// The field of the statistic called `name`, if this model names it.
    fn slot(&mut self, name: &str) -> Option<&mut Option<StatValue>> {
        Some(match name {
            "min" => &mut self.min,
            "max" => &mut self.max,
            "mean" => &mut self.mean,
            "std" => &mut self.std,
            "count" => &mut self.count,
            "q01" => &mut self.q01,
            "q10" => &mut self.q10,
            "q50" => &mut self.q50,
            "q90" => &mut self.q90,
            "q99" => &mut self.q99,
            _ => return None,
        })
    }

    /// Sets the statistic `name` (an unknown name goes to `other`).
    pub fn set(&mut self, name: &str, value: StatValue) {
        match self.slot(name) {
            Some(slot) => *slot = Some(value),
            None => {
                self.other.insert(
                    name.to_string(),
                    serde_json::to_value(&value).unwrap_or(Value::Null),
                );
            }
        }
    }
}

impl InfoJson {
    /// `splits` as episode ranges by name ("from:to"); a range that does not parse is left out
    /// (validate reports it).
    pub fn split_ranges(&self) -> Vec<(String, std::ops::Range<u64>)> {
        (self.splits.iter().flatten())
            .filter_map(|(name, range)| {
                let (from, to) = range.split_once(':')?;
                Some((
                    name.clone(),
                    from.trim().parse().ok()?..to.trim().parse().ok()?,
                ))
            })
            .collect()
    }

    /// Reads `meta/info.json`'s text leniently: only text that is not a JSON object fails.
    pub fn parse(bytes: &[u8]) -> Result<InfoJson, serde_json::Error> {
        serde_json::from_slice(bytes)
    }

    /// Whether the layout is v2.1 (one file per episode, JSON-lines metadata).
    pub fn is_v21(&self) -> bool {
        self.codebase_version.as_deref() == Some("v2.1")
    }

    /// Why `data_path` or `video_path` cannot be a path inside the dataset, if one cannot: only
    /// the placeholders of its version, integer widths within bounds, nothing leading outside.
    /// Every command refuses such a dataset, as `validate` does (exit 1).
    pub fn template_problem(&self) -> Option<String> {
        use crate::export::paths::{self, Field};
        let (chunk, file) = if self.is_v21() {
            ("episode_chunk", "episode_index")
        } else {
            ("chunk_index", "file_index")
        };
        let fields = [
            (chunk, Field::Index(0)),
            (file, Field::Index(0)),
            ("video_key", Field::Name("key")),
        ];
        [
            ("data_path", &self.data_path),
            ("video_path", &self.video_path),
        ]
        .into_iter()
        .find_map(|(name, template)| {
            let template = template.as_ref()?;
            let problem = paths::fill(template, &fields).err()?;
            Some(format!(
                "{name} {template:?} cannot be a path inside the dataset: it {problem}"
            ))
        })
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

    /// Statistics made straight from what a feature states equal those read from its JSON, for
    /// seeded vectors and images of every size, with values JSON cannot hold.
    #[test]
    fn stated_statistics_read_as_from_their_json() {
        use crate::export::stats::{QUANTILES, Stated};
        let mut rng = crate::rng::SplitMix64::stream(11, "stated statistics");
        let odd = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -0.0,
            1e300,
            5e-324,
        ];
        for case in 0..500 {
            let len = (rng.next_u64() % 9) as usize;
            let mut values = || -> Vec<f64> {
                (0..len)
                    .map(|_| match rng.next_u64() % 8 {
                        0 => odd[(rng.next_u64() % odd.len() as u64) as usize],
                        1 => (rng.next_u64() % 1000) as f64,
                        _ => rng.uniform(-1e3, 1e3),
                    })
                    .collect()
            };
            let moments = [values(), values(), values(), values()];
            let known = case % (QUANTILES.len() + 1);
            let quantiles = (QUANTILES[..known].iter())
                .map(|(n, _)| (*n, values()))
                .collect();
            let stated = Stated {
                image: case % 2 == 0,
                moments,
                count: rng.next_u64() >> (case % 64),
                quantiles,
            };
            assert_eq!(
                FeatureStatsJson::from_stated(&stated),
                FeatureStatsJson::from_value(stated.to_json()),
                "{stated:?}"
            );
        }
    }

    #[test]
    fn stat_values_read_as_written() {
        let text = r#"[[[0.5]],[[1]],null,-3,[],1e300]"#;
        let value: StatValue = serde_json::from_str(text).expect("read");
        let written = serde_json::to_string(&value).expect("write");
        assert_eq!(written, r#"[[[0.5]],[[1]],null,-3,[],1e+300]"#);
        assert_eq!(value.depth(), 3);
        assert!(serde_json::from_str::<StatValue>(r#"{"a": 1}"#).is_err());
        assert!(serde_json::from_str::<StatValue>(r#""text""#).is_err());
    }

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
    fn statistics_read_and_write_back_the_same_text() {
        // Integer counts stay integers, floats keep their spelling, (C, 1, 1) nesting stays,
        // unknown statistics follow the named ones.
        let text = r#"{"a":{"min":[0.5,1.0],"max":[1.0,2.0],"mean":[0.75,1.5],"std":[0.0,null],"count":[12],"q01":[[[0.1]]],"extra":"kept"},"b":{"count":[3]}}"#;
        let stats: StatsJson = serde_json::from_str(text).unwrap();
        assert_eq!(serde_json::to_string(&stats).unwrap(), text);
        let a = &stats["a"];
        assert_eq!(a.get("count").unwrap().flat(), [12.0]);
        assert_eq!(a.get("q01").unwrap().depth(), 3);
        assert_eq!(a.get("mean").unwrap().element(1), Some(1.5));
        assert_eq!(a.get("std").unwrap().element(1), None);
        assert_eq!(a.get("q99"), None);
        let names: Vec<&str> = a.named().into_iter().map(|(n, _)| n).collect();
        assert_eq!(names, ["min", "max", "mean", "std", "count", "q01"]);
    }

    #[test]
    fn a_statistic_of_the_wrong_type_reads_as_absent() {
        let stats = FeatureStatsJson::from_value(serde_json::json!({"min": "low", "max": [1.5]}));
        assert_eq!(stats.min, None);
        assert_eq!(stats.max, Some(StatValue::list([1.5])));
        assert_eq!(
            FeatureStatsJson::from_value(serde_json::json!([1])),
            FeatureStatsJson::default()
        );
        // The same as the derived reader, for every kind of value in every place.
        for text in [
            r#"{"min":"low","max":[1.5],"mean":null,"std":[[1,2],[3]],"count":[7],"extra":{"a":1}}"#,
            r#"{"zz":[1],"q99":[true],"q50":[0.5,null],"q01":-3,"q10":18446744073709551615}"#,
            r#"{"q90":{"x":1},"count":"12","min":[[[-0.25]]],"other":null}"#,
            "[1]",
            "7",
        ] {
            let value: Value = serde_json::from_str(text).unwrap();
            let derived: FeatureStatsJson =
                serde_json::from_value(value.clone()).unwrap_or_default();
            assert_eq!(FeatureStatsJson::from_value(value), derived, "{text}");
        }
        let mut set = FeatureStatsJson::default();
        set.set("q50", StatValue::number(f64::NAN));
        set.set("q42", StatValue::list([2.0]));
        assert_eq!(
            serde_json::to_string(&set).unwrap(),
            r#"{"q50":null,"q42":[2.0]}"#
        );
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
