//! Reading an RLDS dataset another tool wrote (an Open X-Embodiment dataset written by
//! tensorflow_datasets): [`ForeignRldsSource`], an [`EpisodeSource`] that takes its features
//! from the dataset's own `features.json`. Every step-level tensor and image becomes a
//! [`FeatureKind::Other`] feature named the LeRobot way (`steps/observation/state` ->
//! `observation.state`, `steps/observation/image` -> `observation.images.image`, `steps/action`
//! -> `action`); `steps/language_instruction` (its first step) is the episode's instruction;
//! `is_first` / `is_last` are structure, not features; other texts and the episode metadata are
//! left out. RLDS has no frame rate: the caller gives one.

use crate::episode::{Dtype, Episode, EpisodeMeta, FeatureKind, FeatureSpec, FeatureValue, Step};
use crate::export::info::DatasetInfo;
use crate::export::rlds::example::{Feature, decode_example};
use crate::export::rlds::generic::{Leaf, leaves};
use crate::export::rlds::read::version_dir;
use crate::export::rlds::tfrecord::{RecordError, RecordReader};
use crate::export::{EpisodeSource, ExportError, read_json};
use serde_json::Value;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

fn invalid(path: &Path, problem: impl Into<String>) -> ExportError {
    ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Keys that are structure, not features.
const STRUCTURE: [&str; 4] = [
    "steps/is_first",
    "steps/is_last",
    "steps/is_terminal",
    "steps/language_instruction",
];

/// The LeRobot name of an RLDS step key.
fn lerobot_name(key: &str, image: bool) -> String {
    let path = key.trim_start_matches("steps/");
    match path.strip_prefix("observation/") {
        Some(rest) if image => format!("observation.images.{}", rest.replace('/', ".")),
        _ => path.replace('/', "."),
    }
}

/// One feature read from the records: its RLDS key and spec.
#[derive(Clone, Debug)]
struct Column {
    key: String,
    spec: FeatureSpec,
}

fn columns(features: &Value, path: &Path) -> Result<Vec<Column>, ExportError> {
    let leaves = leaves(features).map_err(|problem| invalid(path, problem))?;
    let mut columns = Vec::new();
    for (key, leaf) in leaves {
        if !key.starts_with("steps/") || STRUCTURE.contains(&key.as_str()) {
            continue;
        }
        let (dtype, shape) = match &leaf {
            Leaf::Image { shape, .. } => match shape {
                [Some(h), Some(w), Some(c)] => (Dtype::Image, vec![*h, *w, *c]),
                _ => {
                    return Err(invalid(
                        path,
                        format!("{key} is an image of unknown size; surgvla needs fixed sizes"),
                    ));
                }
            },
            Leaf::Tensor { dtype, elements } => match dtype.as_str() {
                "float32" | "float64" | "float16" => (Dtype::Float32, vec![*elements]),
                "int64" | "int32" | "int16" | "int8" | "uint8" | "uint16" | "uint32" | "bool" => {
                    (Dtype::Int64, vec![*elements])
                }
                other => {
                    return Err(invalid(
                        path,
                        format!("{key} is a {other} tensor, which surgvla does not read"),
                    ));
                }
            },
            Leaf::Text => continue,
        };
        columns.push(Column {
            spec: FeatureSpec {
                name: lerobot_name(&key, dtype == Dtype::Image),
                dtype,
                shape,
                names: Vec::new(),
                kind: FeatureKind::Other,
            },
            key,
        });
    }
    Ok(columns)
}

/// Reads an RLDS dataset another tool wrote, episode by episode (one record in memory).
pub struct ForeignRldsSource {
    info: DatasetInfo,
    columns: Vec<Column>,
    shards: std::vec::IntoIter<PathBuf>,
    current: Option<(PathBuf, RecordReader<BufReader<File>>, u64)>,
    total_episodes: u64,
    next_index: u64,
    failed: bool,
}

impl ForeignRldsSource {
    /// Opens the dataset at `path` (a version folder or the data directory above it) with
    /// `fps` steps per second and robot type `robot_type`.
    pub fn open(path: &Path, fps: u32, robot_type: &str) -> Result<Self, ExportError> {
        let folder = version_dir(path)?;
        let info_path = folder.join("dataset_info.json");
        let dataset_info = read_json(&info_path)?;
        let name = dataset_info["name"]
            .as_str()
            .ok_or_else(|| invalid(&info_path, "has no name"))?;
        let lengths: Vec<u64> = dataset_info["splits"]
            .as_array()
            .and_then(|splits| splits.iter().find(|s| s["name"] == "train"))
            .and_then(|split| split["shardLengths"].as_array())
            .ok_or_else(|| invalid(&info_path, "has no train split with shardLengths"))?
            .iter()
            .map(|v| {
                v.as_str()
                    .and_then(|s| s.parse().ok())
                    .or_else(|| v.as_u64())
            })
            .collect::<Option<_>>()
            .ok_or_else(|| invalid(&info_path, "has a shard length that is not a count"))?;
        let count = lengths.len();
        let shards: Vec<PathBuf> = (0..count)
            .map(|i| folder.join(format!("{name}-train.tfrecord-{i:05}-of-{count:05}")))
            .collect();
        if let Some(missing) = shards.iter().find(|p| !p.is_file()) {
            return Err(invalid(missing, "is missing"));
        }
        let features_path = folder.join("features.json");
        let columns = columns(&read_json(&features_path)?, &features_path)?;
        let features: Vec<FeatureSpec> = columns.iter().map(|c| c.spec.clone()).collect();
        let info = DatasetInfo::from_surgvla_json(&Value::Null, fps, robot_type, features);
        Ok(ForeignRldsSource {
            info,
            columns,
            shards: shards.into_iter(),
            current: None,
            total_episodes: lengths.iter().sum(),
            next_index: 0,
            failed: false,
        })
    }

    fn next_record(&mut self) -> Result<Option<(PathBuf, u64, Vec<u8>)>, ExportError> {
        loop {
            if self.current.is_none() {
                let Some(path) = self.shards.next() else {
                    return Ok(None);
                };
                let file = File::open(&path).map_err(ExportError::io(&path))?;
                let reader = RecordReader::new(BufReader::with_capacity(1 << 20, file));
                self.current = Some((path, reader, 0));
            }
            let Some((path, reader, read)) = self.current.as_mut() else {
                continue;
            };
            match reader.next_record() {
                Some(Ok(bytes)) => {
                    *read += 1;
                    return Ok(Some((path.clone(), *read - 1, bytes)));
                }
                Some(Err(RecordError::Io { source, .. })) => {
                    return Err(ExportError::Io {
                        path: path.clone(),
                        source,
                    });
                }
                Some(Err(error)) => return Err(invalid(path, error.to_string())),
                None => self.current = None,
            }
        }
    }

    fn decode(&self, bytes: &[u8], index: u64) -> Result<Episode, String> {
        let example = decode_example(bytes).map_err(|e| e.0.to_string())?;
        let steps = match example.get("steps/is_first") {
            Some(Feature::Int64(flags)) => flags.len(),
            _ => return Err("steps/is_first is missing".into()),
        };
        if steps == 0 {
            return Err("the episode has zero steps".into());
        }
        let instruction = match example.get("steps/language_instruction") {
            Some(Feature::Bytes(texts)) => texts
                .first()
                .map(|t| String::from_utf8_lossy(t).into_owned())
                .unwrap_or_default(),
            _ => String::new(),
        };
        let mut rows: Vec<Vec<FeatureValue>> = vec![Vec::new(); steps];
        for column in &self.columns {
            let n: usize = column.spec.shape.iter().product();
            let wrong = || {
                format!(
                    "{} does not hold {steps} steps of {:?}",
                    column.key, column.spec.shape
                )
            };
            let values = example.get(&column.key).ok_or_else(wrong)?;
            for (i, row) in rows.iter_mut().enumerate() {
                let value = match (column.spec.dtype, values) {
                    (Dtype::Image, Feature::Bytes(images)) => {
                        FeatureValue::Image(images.get(i).ok_or_else(wrong)?.clone())
                    }
                    (Dtype::Float32, Feature::Float(v)) => {
                        FeatureValue::Float32(v.get(i * n..(i + 1) * n).ok_or_else(wrong)?.to_vec())
                    }
                    (Dtype::Int64, Feature::Int64(v)) => {
                        FeatureValue::Int64(v.get(i * n..(i + 1) * n).ok_or_else(wrong)?.to_vec())
                    }
                    _ => return Err(wrong()),
                };
                row.push(value);
            }
        }
        Ok(Episode {
            meta: EpisodeMeta {
                index,
                task_code: String::new(),
                task_name: String::new(),
                level: 0,
                instruction,
                seed: 0,
                attempts: 0,
                success: false,
            },
            steps: rows
                .into_iter()
                .map(|other| Step {
                    other,
                    ..Step::empty()
                })
                .collect(),
        })
    }
}

impl EpisodeSource for ForeignRldsSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.total_episodes
    }

    fn next_episode(&mut self) -> Option<Result<Episode, ExportError>> {
        if self.failed {
            return None;
        }
        let result = match self.next_record() {
            Ok(None) => return None,
            Ok(Some((path, record, bytes))) => {
                let index = self.next_index;
                self.next_index += 1;
                self.decode(&bytes, index)
                    .map_err(|problem| invalid(&path, format!("record {record}: {problem}")))
            }
            Err(error) => Err(error),
        };
        self.failed = result.is_err();
        Some(result)
    }
}
