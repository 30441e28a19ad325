//! Reading an RLDS dataset another tool wrote (an Open X-Embodiment dataset written by
//! tensorflow_datasets): [`ForeignRldsSource`], an [`EpisodeSource`] that takes its features
//! from the dataset's own `features.json`. Every step-level tensor and image becomes a
//! [`FeatureKind::Other`] feature named the LeRobot way (`steps/observation/state` ->
//! `observation.state`, `steps/observation/image` -> `observation.images.image`, `steps/action`
//! -> `action`); `steps/language_instruction` is each step's instruction (the first step's
//! the episode's); `is_first` / `is_last` are structure, not features; other texts and the episode metadata are
//! left out. RLDS has no frame rate: the caller gives one.

use crate::episode::{Dtype, Episode, EpisodeMeta, FeatureKind, FeatureSpec, FeatureValue, Step};
use crate::export::bounded::read_json;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::rlds::example::{Feature, decode_example};
use crate::export::rlds::generic::{Leaf, leaves};
use crate::export::rlds::options::SURGVLA_JSON;
use crate::export::rlds::read::{ShardRecords, invalid, version_dir};
use crate::export::source::EpisodeSource;
use serde_json::Value;
use std::path::Path;

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
            // One text per step: a string feature (e.g. instruction.text).
            Leaf::Text => (Dtype::String, vec![1]),
        };
        columns.push(Column {
            spec: FeatureSpec {
                name: lerobot_name(&key, dtype == Dtype::Image),
                dtype,
                shape,
                names: Vec::new(),
                kind: FeatureKind::Other,
                video: None,
                info: Default::default(),
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
    records: ShardRecords,
    next_index: u64,
}

impl ForeignRldsSource {
    /// Opens the dataset at `path` (a version folder or the data directory above it) with
    /// `fps` steps per second and robot type `robot_type`.
    pub fn open(path: &Path, fps: u32, robot_type: &str) -> Result<Self, ExportError> {
        let folder = version_dir(path)?;
        let records = ShardRecords::open(&folder)?;
        let features_path = folder.join("features.json");
        let columns = columns(&read_json(&features_path)?, &features_path)?;
        let features: Vec<FeatureSpec> = columns.iter().map(|c| c.spec.clone()).collect();
        let info = DatasetInfo::from_surgvla_json(&Value::Null, fps, robot_type, features);
        Ok(ForeignRldsSource {
            info,
            columns,
            records,
            next_index: 0,
        })
    }

    /// Episode `index` from its record.
    fn decode(columns: &[Column], bytes: &[u8], index: u64) -> Result<Episode, String> {
        let example = decode_example(bytes).map_err(|e| e.0.to_string())?;
        let steps = match example.get("steps/is_first") {
            Some(Feature::Int64(flags)) => flags.len(),
            _ => return Err("steps/is_first is missing".into()),
        };
        if steps == 0 {
            return Err("the episode has zero steps".into());
        }
        let texts: Vec<String> = match example.get("steps/language_instruction") {
            Some(Feature::Bytes(texts)) => (texts.iter())
                .map(|t| String::from_utf8_lossy(t).into_owned())
                .collect(),
            _ => Vec::new(),
        };
        let task_changes = EpisodeMeta::changes_of(texts.iter().map(String::as_str));
        let instruction = texts.into_iter().next().unwrap_or_default();
        let mut rows: Vec<Vec<FeatureValue>> = vec![Vec::new(); steps];
        for column in columns {
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
                    (Dtype::String, Feature::Bytes(texts)) => FeatureValue::Text(
                        String::from_utf8_lossy(texts.get(i).ok_or_else(wrong)?).into_owned(),
                    ),
                    _ => return Err(wrong()),
                };
                row.push(value);
            }
        }
        Ok(Episode {
            encoded: Vec::new(),
            image_stats: Vec::new(),
            meta: EpisodeMeta {
                task_changes,
                ..EpisodeMeta::foreign(index, instruction)
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
impl Iterator for ForeignRldsSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let index = self.next_index;
        self.next_index += 1;
        let columns = &self.columns;
        self.records
            .next_decoded(|bytes| Self::decode(columns, bytes, index))
    }
}

impl EpisodeSource for ForeignRldsSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.records.total()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next_index += 1;
        self.records.next_decoded(|_| Ok(()))
    }
}

/// Reads an RLDS version folder: ours (with `surgvla.json`), or another tool's through its own
/// `features.json`, which needs `options.fps`.
pub fn open_any(
    folder: &std::path::Path,
    options: &crate::export::source::SourceOptions,
) -> Result<Box<dyn crate::export::source::EpisodeSource + Send>, ExportError> {
    if folder.join(SURGVLA_JSON).is_file() {
        return Ok(Box::new(super::read::RldsSource::open(folder)?));
    }
    let fps = options.fps.ok_or_else(|| ExportError::NoFrameRate {
        path: folder.to_path_buf(),
    })?;
    let robot_type = options.robot_type.as_deref().unwrap_or("unknown");
    Ok(Box::new(super::foreign::ForeignRldsSource::open(
        folder, fps, robot_type,
    )?))
}
