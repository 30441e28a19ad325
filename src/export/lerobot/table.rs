//! Arrow tables of a LeRobot dataset: the frame table (one row per step, a row group per
//! episode or per part of one), `tasks.parquet` with its pandas index metadata, and the episodes table.

use super::meta::{StatValue, StatsJson};
use crate::episode::{Dtype, Episode, FeatureKind, FeatureSpec, FeatureValue};
use crate::export::error::ExportError;
use arrow_array::builder::{Float64Builder, Int64Builder, ListBuilder, StringBuilder};
use arrow_array::{
    Array, ArrayRef, BinaryArray, BooleanArray, FixedSizeListArray, Float32Array, Int64Array,
    RecordBatch, StringArray, StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema};
use serde_json::Value;
use serde_json::value::RawValue;
use std::collections::HashMap;
use std::sync::Arc;

/// The struct LeRobot (Hugging Face `datasets.Image`) stores an image as.
pub fn image_fields() -> Fields {
    Fields::from(vec![
        Field::new("bytes", DataType::Binary, true),
        Field::new("path", DataType::Utf8, true),
    ])
}

fn list_item(dtype: DataType) -> Arc<Field> {
    Arc::new(Field::new("item", dtype, true))
}

/// The five columns LeRobot requires after the features.
pub const DEFAULT_COLUMNS: [&str; 5] = [
    "timestamp",
    "frame_index",
    "episode_index",
    "index",
    "task_index",
];

/// Values per step of a vector feature.
fn elements(feature: &FeatureSpec) -> usize {
    feature.shape.iter().product()
}

/// Whether a feature is a plain column: another dataset's shape-[1] feature (ours are lists).
fn is_scalar(feature: &FeatureSpec) -> bool {
    feature.kind == FeatureKind::Other && feature.shape == [1]
}

/// The frame table's schema: features in order, then the defaults.
pub fn frame_schema(features: &[FeatureSpec]) -> Arc<Schema> {
    let mut fields: Vec<Field> = features
        .iter()
        .map(|f| match f.dtype {
            Dtype::Image => Field::new(&f.name, DataType::Struct(image_fields()), true),
            Dtype::String => Field::new(&f.name, DataType::Utf8, true),
            // Another robot's one-value feature is a plain column, as lerobot writes it.
            Dtype::Float32 if is_scalar(f) => Field::new(&f.name, DataType::Float32, true),
            Dtype::Float64 if is_scalar(f) => Field::new(&f.name, DataType::Float64, true),
            Dtype::Int64 if is_scalar(f) => Field::new(&f.name, DataType::Int64, true),
            Dtype::Float32 => Field::new(
                &f.name,
                DataType::FixedSizeList(list_item(DataType::Float32), elements(f) as i32),
                true,
            ),
            Dtype::Int64 => Field::new(
                &f.name,
                DataType::FixedSizeList(list_item(DataType::Int64), elements(f) as i32),
                true,
            ),
            Dtype::Float64 => Field::new(
                &f.name,
                DataType::FixedSizeList(list_item(DataType::Float64), elements(f) as i32),
                true,
            ),
        })
        .collect();
    fields.push(Field::new("timestamp", DataType::Float32, true));
    for name in &DEFAULT_COLUMNS[1..] {
        fields.push(Field::new(*name, DataType::Int64, true));
    }
    Arc::new(Schema::new(fields))
}

/// Encoded image bytes of one episode, per image feature.
pub(super) type EncodedImages = HashMap<String, ImageColumn>;

/// One image feature's encoded frames of an episode, back to back in one buffer: the parquet
/// column's values as they are, so appending the episode copies none of them again.
#[derive(Debug)]
pub struct ImageColumn {
    values: Vec<u8>,
    /// Where each frame starts in `values`, then its end (so never empty).
    offsets: Vec<i32>,
}

impl ImageColumn {
    /// An empty column with room for `frames` images of about `bytes_per_frame` bytes.
    pub fn with_capacity(frames: usize, bytes_per_frame: usize) -> Self {
        let mut offsets = Vec::with_capacity(frames + 1);
        offsets.push(0);
        ImageColumn {
            values: Vec::with_capacity(frames.saturating_mul(bytes_per_frame)),
            offsets,
        }
    }

    /// Appends one frame that `write` encodes at the end of the buffer.
    pub fn push_with<E>(
        &mut self,
        write: impl FnOnce(&mut Vec<u8>) -> Result<(), E>,
    ) -> Result<(), E>
    where
        E: From<ExportError>,
    {
        write(&mut self.values)?;
        let end = i32::try_from(self.values.len()).map_err(|_| {
            ExportError::InvalidEpisode(
                "an episode's images of one feature exceed 2 GiB, one parquet column's limit"
                    .into(),
            )
        })?;
        self.offsets.push(end);
        Ok(())
    }

    /// Frames already encoded.
    pub fn from_frames<'a, I>(frames: I) -> Result<Self, ExportError>
    where
        I: IntoIterator<Item = &'a [u8]>,
        I::IntoIter: Clone,
    {
        let frames = frames.into_iter();
        let (count, total) = frames.clone().fold((0, 0), |(count, total), frame| {
            (count + 1, total + frame.len())
        });
        let mut column = ImageColumn::with_capacity(count, 0);
        column.values.reserve_exact(total);
        for frame in frames {
            column.push_with(|out| {
                out.extend_from_slice(frame);
                Ok::<(), ExportError>(())
            })?;
        }
        Ok(column)
    }

    /// Frames in the column.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// The column as arrow's binary array, without copying the bytes.
    fn into_array(self) -> arrow_array::BinaryArray {
        arrow_array::BinaryArray::new(
            arrow_buffer::OffsetBuffer::new(arrow_buffer::ScalarBuffer::from(self.offsets)),
            arrow_buffer::Buffer::from_vec(self.values),
            None,
        )
    }
}

/// What the parquet's columns are: its schema, its features, and where each of its
/// [`FeatureKind::Other`] features is among a step's other values (video features have values
/// in steps but no column).
pub(super) struct ParquetColumns<'a> {
    pub schema: &'a Arc<Schema>,
    pub features: &'a [FeatureSpec],
    pub other_positions: &'a [usize],
}

/// The rows of one episode, or of a part of one whose first step is the episode's
/// `first_step`-th (frame indices and timestamps count from the episode's start); the first
/// row's dataset index is `first_index`.
pub(super) fn frame_batch(
    columns_of: &ParquetColumns<'_>,
    episode: &Episode,
    mut images: EncodedImages,
    (first_index, first_step): (u64, usize),
    task_indices: &[u64],
    fps: u32,
) -> Result<RecordBatch, ExportError> {
    let (schema, features, other_positions) = (
        columns_of.schema,
        columns_of.features,
        columns_of.other_positions,
    );
    let n = episode.steps.len();
    let mut columns: Vec<ArrayRef> = Vec::with_capacity(features.len() + 5);
    let mut other = 0usize;
    for feature in features {
        let column: ArrayRef = match feature.kind {
            FeatureKind::Other => {
                let position = other_positions.get(other).copied().ok_or_else(|| {
                    ExportError::Internal(format!("no step value for {}", feature.name))
                })?;
                other += 1;
                other_column(feature, episode, position)?
            }
            FeatureKind::Rgb | FeatureKind::Depth | FeatureKind::Mask => {
                let encoded = images.remove(&feature.name).ok_or_else(|| {
                    ExportError::Internal(format!("no encoded images for {}", feature.name))
                })?;
                if encoded.len() != n {
                    return Err(ExportError::Internal(format!(
                        "{} encoded images of {} for {n} steps",
                        encoded.len(),
                        feature.name
                    )));
                }
                let bytes = encoded.into_array();
                let paths = StringArray::new_null(n);
                Arc::new(StructArray::new(
                    image_fields(),
                    vec![Arc::new(bytes), Arc::new(paths)],
                    None,
                ))
            }
            FeatureKind::State | FeatureKind::Action | FeatureKind::EnvironmentState => {
                let values: Vec<f32> = episode
                    .steps
                    .iter()
                    .flat_map(|s| match feature.kind {
                        FeatureKind::State => s.state.to_vec(),
                        FeatureKind::Action => s.action.to_vec(),
                        _ => s.environment_state.to_vec(),
                    })
                    .collect();
                Arc::new(FixedSizeListArray::new(
                    list_item(DataType::Float32),
                    feature.shape[0] as i32,
                    Arc::new(Float32Array::from(values)),
                    None,
                ))
            }
        };
        columns.push(column);
    }
    if task_indices.len() != n {
        return Err(ExportError::Internal(format!(
            "{} task indices for {n} steps",
            task_indices.len()
        )));
    }
    columns.extend(default_columns(
        episode.meta.index,
        (first_index, first_step),
        task_indices,
        fps,
    ));
    Ok(RecordBatch::try_new(schema.clone(), columns)?)
}

/// The default columns (timestamp, frame, episode and dataset indices, task) of rows of
/// episode `episode_index` from its `first_step`-th step, the dataset's `first_index`-th frame
/// on, one per task index.
pub(super) fn default_columns(
    episode_index: u64,
    (first_index, first_step): (u64, usize),
    task_indices: &[u64],
    fps: u32,
) -> [ArrayRef; 5] {
    let n = task_indices.len();
    let steps = first_step..first_step + n;
    let timestamps: Vec<f32> = (steps.clone())
        .map(|i| (i as f64 / f64::from(fps)) as f32)
        .collect();
    [
        Arc::new(Float32Array::from(timestamps)),
        Arc::new(Int64Array::from_iter_values(steps.map(|i| i as i64))),
        Arc::new(Int64Array::from_iter_values(std::iter::repeat_n(
            episode_index as i64,
            n,
        ))),
        Arc::new(Int64Array::from_iter_values(
            (0..n).map(|i| (first_index + i as u64) as i64),
        )),
        Arc::new(Int64Array::from_iter_values(
            task_indices.iter().map(|&t| t as i64),
        )),
    ]
}

/// `batch` with each variable-length list column (`List`, `LargeList`: what pandas and
/// lerobot's edit tool write where lerobot's own writer writes fixed-size lists) as the
/// fixed-size list its rows' common length makes, so that every reader sees one shape. A
/// column whose rows differ in length, or hold a null, is left as it is (a type check names
/// it).
pub fn fixed_size_lists(batch: RecordBatch) -> RecordBatch {
    let schema = batch.schema();
    let mut changed = false;
    let mut fields = Vec::with_capacity(schema.fields().len());
    let mut columns = Vec::with_capacity(schema.fields().len());
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        match fixed_size(column.as_ref()) {
            Some(fixed) => {
                changed = true;
                fields.push(Arc::new(Field::new(
                    field.name(),
                    fixed.data_type().clone(),
                    field.is_nullable(),
                )));
                columns.push(Arc::new(fixed) as ArrayRef);
            }
            None => {
                fields.push(field.clone());
                columns.push(column.clone());
            }
        }
    }
    if !changed {
        return batch;
    }
    let schema = Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone()));
    RecordBatch::try_new(schema, columns).unwrap_or(batch)
}

/// A variable-length list column whose rows all hold the same number of values (and no
/// null) as a fixed-size list; None for any other column.
fn fixed_size(column: &dyn Array) -> Option<FixedSizeListArray> {
    let any = column.as_any();
    let (offsets, values, item): (Vec<usize>, ArrayRef, Arc<Field>) =
        if let Some(list) = any.downcast_ref::<arrow_array::ListArray>() {
            let DataType::List(item) = list.data_type() else {
                return None;
            };
            let offsets = list.value_offsets().iter().map(|&o| o as usize).collect();
            (offsets, list.values().clone(), item.clone())
        } else if let Some(list) = any.downcast_ref::<arrow_array::LargeListArray>() {
            let DataType::LargeList(item) = list.data_type() else {
                return None;
            };
            let offsets = list.value_offsets().iter().map(|&o| o as usize).collect();
            (offsets, list.values().clone(), item.clone())
        } else {
            return None;
        };
    let numeric = matches!(
        item.data_type(),
        DataType::Float32 | DataType::Float64 | DataType::Int64 | DataType::Int32
    );
    if !numeric || column.null_count() > 0 || offsets.len() < 2 {
        return None;
    }
    let n = offsets[1] - offsets[0];
    if n == 0 || offsets.windows(2).any(|w| w[1] - w[0] != n) {
        return None;
    }
    let (first, last) = (offsets[0], offsets[offsets.len() - 1]);
    let values = values.slice(first, last - first);
    FixedSizeListArray::try_new(item, i32::try_from(n).ok()?, values, None).ok()
}

/// `values` as one binary array, its buffer sized once (images: hundreds of MB an episode).
fn binary_array(values: &[&[u8]]) -> BinaryArray {
    let total = values.iter().map(|v| v.len()).sum();
    let mut builder = arrow_array::builder::BinaryBuilder::with_capacity(values.len(), total);
    for value in values {
        builder.append_value(value);
    }
    builder.finish()
}

/// The column of the `position`-th [`FeatureKind::Other`] feature: its values as they came.
fn other_column(
    feature: &FeatureSpec,
    episode: &Episode,
    position: usize,
) -> Result<ArrayRef, ExportError> {
    let values = episode.steps.iter().map(|s| s.other.get(position));
    let wrong = || {
        ExportError::InvalidEpisode(format!(
            "episode {}: {} does not hold {:?} values",
            episode.meta.index, feature.name, feature.dtype
        ))
    };
    let scalar = is_scalar(feature);
    let n = elements(feature) as i32;
    // A plain column for shape [1], else fixed-size lists of `n`.
    let vector = |flat: ArrayRef, item: DataType| -> ArrayRef {
        if scalar {
            flat
        } else {
            Arc::new(FixedSizeListArray::new(list_item(item), n, flat, None))
        }
    };
    Ok(match feature.dtype {
        Dtype::Image => {
            let mut bytes = Vec::with_capacity(episode.steps.len());
            for value in values {
                match value {
                    Some(FeatureValue::Image(b)) => bytes.push(b.as_slice()),
                    _ => return Err(wrong()),
                }
            }
            Arc::new(StructArray::new(
                image_fields(),
                vec![
                    Arc::new(binary_array(&bytes)),
                    Arc::new(StringArray::new_null(episode.steps.len())),
                ],
                None,
            ))
        }
        Dtype::Float32 => {
            let mut flat = Vec::new();
            for value in values {
                match value {
                    Some(FeatureValue::Float32(v)) => flat.extend_from_slice(v),
                    _ => return Err(wrong()),
                }
            }
            vector(Arc::new(Float32Array::from(flat)), DataType::Float32)
        }
        Dtype::Float64 => {
            let mut flat = Vec::new();
            for value in values {
                match value {
                    Some(FeatureValue::Float64(v)) => flat.extend_from_slice(v),
                    _ => return Err(wrong()),
                }
            }
            vector(
                Arc::new(arrow_array::Float64Array::from(flat)),
                DataType::Float64,
            )
        }
        Dtype::Int64 => {
            let mut flat = Vec::new();
            for value in values {
                match value {
                    Some(FeatureValue::Int64(v)) => flat.extend_from_slice(v),
                    _ => return Err(wrong()),
                }
            }
            vector(Arc::new(Int64Array::from(flat)), DataType::Int64)
        }
        Dtype::String => {
            let mut texts = Vec::with_capacity(episode.steps.len());
            for value in values {
                match value {
                    Some(FeatureValue::Text(text)) => texts.push(text.as_str()),
                    _ => return Err(wrong()),
                }
            }
            Arc::new(StringArray::from(texts))
        }
    })
}

/// `tasks.parquet`: task_index and task, written as a pandas frame indexed by the task string.
pub(super) fn tasks_batch(tasks: &[String]) -> Result<RecordBatch, ExportError> {
    let pandas = serde_json::json!({
        "index_columns": ["task"],
        "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": null}
        ],
        "creator": {"library": "surgvla", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.2.3"
    });
    let metadata = HashMap::from([("pandas".to_string(), pandas.to_string())]);
    let schema = Schema::new(vec![
        Field::new("task_index", DataType::Int64, true),
        Field::new("task", DataType::Utf8, true),
    ])
    .with_metadata(metadata);
    let indices = Int64Array::from_iter_values((0..tasks.len()).map(|i| i as i64));
    let names = StringArray::from_iter_values(tasks.iter());
    Ok(RecordBatch::try_new(
        Arc::new(schema),
        vec![Arc::new(indices), Arc::new(names)],
    )?)
}

/// One row of the episodes table.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, Default)]
pub(super) struct EpisodeRow {
    pub episode_index: u64,
    /// The episode's instructions, each once, in the order they first hold.
    pub tasks: Vec<String>,
    pub length: u64,
    pub data_chunk: u64,
    pub data_file: u64,
    pub from_index: u64,
    pub to_index: u64,
    /// Per feature, its statistics object (min, max, ... q99), as in stats.json and v2.1's
    /// episodes_stats.jsonl; the episodes table flattens it to `stats/<feature>/<stat>` columns.
    pub stats: StatsJson,
    /// Where each video feature's frames are.
    pub videos: Vec<KeyedSpan>,
    /// Per video feature of a surgvla dataset, the exact statistics accumulator of its pixels
    /// (null when unknown): the `surgvla/pixel_stats/<feature>` column. Held, journaled and
    /// written as the JSON text it was read or made as ([`raw_json`]).
    #[serde(default)]
    pub pixel_stats: Vec<(String, Box<RawValue>)>,
    /// Where the episode came from, for surgvla's own episodes only: another tool's dataset
    /// or a robot's recordings get no `surgvla/...` columns rather than placeholders.
    #[serde(default)]
    pub provenance: Option<Provenance>,
    /// Per-episode values another tool's dataset recorded ([`crate::episode::EpisodeMeta::fields`]).
    #[serde(default)]
    pub fields: serde_json::Map<String, Value>,
}

/// `text` as one JSON value held as its text: null when it is not one.
pub(super) fn raw_json(text: String) -> Box<RawValue> {
    RawValue::from_string(text).unwrap_or_else(|_| RawValue::NULL.to_owned())
}

/// One episode's row of the episodes metadata as a reader sees it (v3.0's parquet row, or v2.1's
/// `episodes.jsonl` line with its `episodes_stats.jsonl` line), read leniently: a column of the
/// wrong type reads as absent.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct StoredEpisode {
    /// Per video feature, where its frames are (v3.0: the four `videos/<key>/...` columns).
    pub videos: std::collections::BTreeMap<String, VideoSpan>,
    /// Per feature, its statistics (v3.0: the `stats/<feature>/<stat>` columns).
    pub stats: StatsJson,
    /// Per video feature of a surgvla dataset, the exact statistics accumulator of its pixels
    /// (the `surgvla/pixel_stats/<feature>` column, JSON text or an object), kept as compact
    /// JSON text: parsed, each is tens of kilobytes (histograms), and a reader holds every
    /// episode's row; the episode being read parses its own.
    pub pixel_stats: std::collections::BTreeMap<String, String>,
    /// The `surgvla/...` columns (each absent one reads as zero, empty or false).
    pub provenance: Provenance,
    /// Another tool's own columns (see [`free_field_name`]), nulls left out.
    pub fields: serde_json::Map<String, Value>,
}

impl StoredEpisode {
    /// The episode whose columns, keyed the v3.0 way, are `columns`.
    pub(super) fn from_columns<'a>(columns: impl IntoIterator<Item = (&'a str, Value)>) -> Self {
        let mut episode = StoredEpisode::default();
        let mut spans: std::collections::BTreeMap<String, [Option<f64>; 4]> = Default::default();
        for (name, value) in columns {
            let p = &mut episode.provenance;
            match name {
                "surgvla/seed" => p.seed = value.as_i64().unwrap_or(0) as u64,
                "surgvla/task_id" => p.task_id = value.as_str().unwrap_or_default().into(),
                "surgvla/level" => p.level = value.as_u64().unwrap_or(0) as u8,
                "surgvla/attempts" => p.attempts = value.as_u64().unwrap_or(0) as u32,
                "surgvla/success" => p.success = value.as_bool().unwrap_or(false),
                _ => {}
            }
            if free_field_name(name) && !value.is_null() {
                episode.fields.insert(name.to_string(), value);
                continue;
            }
            if let Some(key) = name.strip_prefix(PIXEL_STATS) {
                // Parsed where it is used (an accumulator that does not parse is left out
                // there); only what cannot be one is dropped here.
                let exact = match value {
                    Value::String(text) => text.trim_start().starts_with('{').then_some(text),
                    Value::Object(_) => Some(value.to_string()),
                    _ => None,
                };
                if let Some(exact) = exact {
                    episode.pixel_stats.insert(key.to_string(), exact);
                }
            } else if name.starts_with(STATS) {
                episode.set_stat(name, serde_json::from_value::<StatValue>(value).ok());
            } else if let Some((key, part)) = name
                .strip_prefix("videos/")
                .and_then(|n| n.rsplit_once('/'))
            {
                let slot = [
                    "chunk_index",
                    "file_index",
                    "from_timestamp",
                    "to_timestamp",
                ]
                .iter()
                .position(|p| *p == part);
                if let Some(slot) = slot {
                    spans.entry(key.to_string()).or_default()[slot] = value.as_f64();
                }
            }
        }
        for (key, parts) in spans {
            if let [Some(chunk), Some(file), Some(from_secs), Some(to_secs)] = parts {
                let span = VideoSpan {
                    chunk: chunk as u64,
                    file: file as u64,
                    from_secs,
                    to_secs,
                };
                episode.videos.insert(key, span);
            }
        }
        episode
    }

    /// Puts in the statistic of column `name` (`stats/<feature>/<stat>`): `value`, None when
    /// the cell is not numbers (left out).
    pub(super) fn set_stat(&mut self, name: &str, value: Option<StatValue>) {
        let place = name.strip_prefix(STATS).and_then(|n| n.rsplit_once('/'));
        if let (Some((feature, stat)), Some(value)) = (place, value) {
            let entry = self.stats.entry(feature.to_string()).or_default();
            entry.set(stat, value);
        }
    }
}

/// The prefix of an episodes table's statistics columns (`stats/<feature>/<stat>`).
pub(super) const STATS: &str = "stats/";

/// A video feature's span.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub(super) struct KeyedSpan {
    pub key: String,
    pub span: VideoSpan,
}

/// The episodes table's column prefix of a video feature's exact pixel statistics.
pub(super) const PIXEL_STATS: &str = "surgvla/pixel_stats/";

/// Where an episode came from: what it takes to re-run or audit it. Stored as the `surgvla/...`
/// columns of the episodes table (v3.0) or keys of `episodes.jsonl` (v2.1).
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, Default, PartialEq)]
pub struct Provenance {
    pub seed: u64,
    pub task_id: String,
    pub level: u8,
    pub attempts: u32,
    pub success: bool,
}

impl Provenance {
    /// An episode's provenance as its metadata says it.
    pub fn of(meta: &crate::episode::EpisodeMeta) -> Self {
        Provenance {
            seed: meta.seed,
            task_id: meta.task_code.clone(),
            level: meta.level,
            attempts: meta.attempts,
            success: meta.success,
        }
    }
    /// The columns' keys, in column order.
    pub const KEYS: [&'static str; 5] = [
        "surgvla/seed",
        "surgvla/task_id",
        "surgvla/level",
        "surgvla/attempts",
        "surgvla/success",
    ];

    /// (key, value) of each field, in column order.
    pub fn columns(&self) -> [(&'static str, Value); 5] {
        let [seed, task_id, level, attempts, success] = Self::KEYS;
        [
            (seed, Value::from(self.seed as i64)),
            (task_id, Value::from(self.task_id.as_str())),
            (level, Value::from(self.level)),
            (attempts, Value::from(self.attempts)),
            (success, Value::from(self.success)),
        ]
    }
}

/// An episode's place in a video file.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq)]
pub(super) struct VideoSpan {
    pub chunk: u64,
    pub file: u64,
    pub from_secs: f64,
    pub to_secs: f64,
}

/// A column of nested lists of f64 (depth 1 or 3) or of i64 counts, one entry per episode (an
/// absent statistic is an empty list).
fn stats_column(values: &[Option<&StatValue>], name: &str) -> ArrayRef {
    let flat = |v: &Option<&StatValue>| v.map(|v| v.flat()).unwrap_or_default();
    if name.ends_with("/count") {
        let mut builder = ListBuilder::new(Int64Builder::new());
        for v in values {
            for x in flat(v) {
                builder.values().append_value(x as i64);
            }
            builder.append(true);
        }
        return Arc::new(builder.finish());
    }
    if values.first().map_or(1, |v| v.map_or(0, StatValue::depth)) == 3 {
        let mut builder =
            ListBuilder::new(ListBuilder::new(ListBuilder::new(Float64Builder::new())));
        for v in values {
            for channel in v.map(StatValue::items).unwrap_or_default() {
                for row in channel.items() {
                    for x in row.flat() {
                        builder.values().values().values().append_value(x);
                    }
                    builder.values().values().append(true);
                }
                builder.values().append(true);
            }
            builder.append(true);
        }
        return Arc::new(builder.finish());
    }
    let mut builder = ListBuilder::new(Float64Builder::new());
    for v in values {
        for x in flat(v) {
            builder.values().append_value(x);
        }
        builder.append(true);
    }
    Arc::new(builder.finish())
}

/// An int64 column of `f` of each row.
fn int_column(rows: &[EpisodeRow], f: &dyn Fn(&EpisodeRow) -> u64) -> ArrayRef {
    Arc::new(Int64Array::from_iter_values(
        rows.iter().map(|r| f(r) as i64),
    ))
}

/// The episodes table's columns of video feature `key`: each episode's file and span.
fn video_columns(rows: &[EpisodeRow], key: &str) -> Vec<(String, ArrayRef)> {
    let int = |f: &dyn Fn(&EpisodeRow) -> u64| int_column(rows, f);
    let mut columns: Vec<(String, ArrayRef)> = Vec::with_capacity(4);
    let span = |r: &EpisodeRow| {
        r.videos.iter().find(|v| v.key == *key).map_or(
            VideoSpan {
                chunk: 0,
                file: 0,
                from_secs: 0.0,
                to_secs: 0.0,
            },
            |v| v.span,
        )
    };
    columns.push((format!("videos/{key}/chunk_index"), int(&|r| span(r).chunk)));
    columns.push((format!("videos/{key}/file_index"), int(&|r| span(r).file)));
    columns.push((
        format!("videos/{key}/from_timestamp"),
        Arc::new(arrow_array::Float64Array::from_iter_values(
            rows.iter().map(|r| span(r).from_secs),
        )),
    ));
    columns.push((
        format!("videos/{key}/to_timestamp"),
        Arc::new(arrow_array::Float64Array::from_iter_values(
            rows.iter().map(|r| span(r).to_secs),
        )),
    ));
    columns
}

/// The episodes table's provenance columns, when every episode has its provenance (none
/// for another tool's episodes); the seed as int64 (two's complement: seeds above 2^63 read
/// negative).
fn provenance_columns(rows: &[EpisodeRow]) -> Vec<(String, ArrayRef)> {
    let Some(known) = rows
        .iter()
        .map(|r| r.provenance.as_ref())
        .collect::<Option<Vec<_>>>()
    else {
        return Vec::new();
    };
    let int = |f: &dyn Fn(&Provenance) -> u64| -> ArrayRef {
        Arc::new(Int64Array::from_iter_values(
            known.iter().map(|p| f(p) as i64),
        ))
    };
    let provenance: [ArrayRef; 5] = [
        int(&|p| p.seed),
        Arc::new(StringArray::from_iter_values(
            known.iter().map(|p| p.task_id.as_str()),
        )),
        int(&|p| u64::from(p.level)),
        int(&|p| u64::from(p.attempts)),
        Arc::new(BooleanArray::from(
            known.iter().map(|p| p.success).collect::<Vec<_>>(),
        )),
    ];
    (Provenance::KEYS.iter().map(|k| k.to_string()))
        .zip(provenance)
        .collect()
}

/// Whether a per-episode field of another tool may be a column of this name: not one of the
/// table's own.
pub(super) fn free_field_name(name: &str) -> bool {
    const OWN: [&str; 9] = [
        "episode_index",
        "tasks",
        "length",
        "dataset_from_index",
        "dataset_to_index",
        "data/",
        "meta/",
        "stats/",
        "videos/",
    ];
    !name.is_empty()
        && !name.starts_with("surgvla/")
        && !OWN
            .iter()
            .any(|own| name == *own || (own.ends_with('/') && name.starts_with(own)))
}

/// The columns of the episodes' own fields (the first episode's keys): strings, integers,
/// floats or booleans when every episode's value is one, else each value's JSON text; an
/// episode without the field holds null.
fn field_columns(rows: &[EpisodeRow]) -> Vec<(String, ArrayRef)> {
    let Some(first) = rows.first() else {
        return Vec::new();
    };
    let mut columns = Vec::new();
    for key in first.fields.keys().filter(|k| free_field_name(k)) {
        let values: Vec<Option<&Value>> = rows.iter().map(|r| r.fields.get(key)).collect();
        let all = |test: &dyn Fn(&Value) -> bool| values.iter().flatten().all(|v| test(v));
        let column: ArrayRef = if all(&Value::is_string) {
            Arc::new(StringArray::from(
                (values.iter())
                    .map(|v| v.and_then(Value::as_str))
                    .collect::<Vec<_>>(),
            ))
        } else if all(&Value::is_boolean) {
            Arc::new(BooleanArray::from(
                (values.iter())
                    .map(|v| v.and_then(Value::as_bool))
                    .collect::<Vec<_>>(),
            ))
        } else if all(&Value::is_i64) {
            Arc::new(Int64Array::from(
                (values.iter())
                    .map(|v| v.and_then(Value::as_i64))
                    .collect::<Vec<_>>(),
            ))
        } else if all(&Value::is_number) {
            Arc::new(arrow_array::Float64Array::from(
                (values.iter())
                    .map(|v| v.and_then(Value::as_f64))
                    .collect::<Vec<_>>(),
            ))
        } else {
            Arc::new(StringArray::from(
                (values.iter())
                    .map(|v| v.map(Value::to_string))
                    .collect::<Vec<_>>(),
            ))
        };
        columns.push((key.clone(), column));
    }
    columns
}

/// The episodes table (episode_index equals row order); `video_keys` are the video features.
pub(super) fn episodes_batch(
    rows: &[EpisodeRow],
    video_keys: &[String],
) -> Result<RecordBatch, ExportError> {
    let int = |f: &dyn Fn(&EpisodeRow) -> u64| -> ArrayRef {
        Arc::new(Int64Array::from_iter_values(
            rows.iter().map(|r| f(r) as i64),
        ))
    };
    let mut tasks = ListBuilder::new(StringBuilder::new());
    for row in rows {
        for task in &row.tasks {
            tasks.values().append_value(task);
        }
        tasks.append(true);
    }
    let mut columns: Vec<(String, ArrayRef)> = vec![
        ("episode_index".into(), int(&|r| r.episode_index)),
        ("tasks".into(), Arc::new(tasks.finish())),
        ("length".into(), int(&|r| r.length)),
        ("data/chunk_index".into(), int(&|r| r.data_chunk)),
        ("data/file_index".into(), int(&|r| r.data_file)),
        ("dataset_from_index".into(), int(&|r| r.from_index)),
        ("dataset_to_index".into(), int(&|r| r.to_index)),
        ("meta/episodes/chunk_index".into(), int(&|_| 0)),
        ("meta/episodes/file_index".into(), int(&|_| 0)),
    ];
    for key in video_keys {
        columns.extend(video_columns(rows, key));
    }
    if let Some(first) = rows.first() {
        for (feature, stats) in &first.stats {
            for (stat, _) in stats.named() {
                let name = format!("stats/{feature}/{stat}");
                let values: Vec<Option<&StatValue>> = rows
                    .iter()
                    .map(|r| r.stats.get(feature).and_then(|s| s.get(stat)))
                    .collect();
                columns.push((name.clone(), stats_column(&values, &name)));
            }
        }
    }
    columns.extend(provenance_columns(rows));
    columns.extend(field_columns(rows));
    let stats_keys: Vec<&String> = rows
        .first()
        .map(|r| r.pixel_stats.iter().map(|(k, _)| k).collect())
        .unwrap_or_default();
    for key in stats_keys {
        let texts = rows.iter().map(|r| {
            r.pixel_stats
                .iter()
                .find(|(k, _)| k == key)
                .filter(|(_, v)| v.get() != "null")
                .map(|(_, v)| v.get())
        });
        columns.push((
            format!("{PIXEL_STATS}{key}"),
            Arc::new(StringArray::from_iter(texts)),
        ));
    }
    let fields: Vec<Field> = columns
        .iter()
        .map(|(name, array)| Field::new(name, array.data_type().clone(), true))
        .collect();
    let arrays = columns.into_iter().map(|(_, a)| a).collect();
    Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), arrays)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// Another tool's per-episode fields become typed columns (text, integer, float, boolean;
    /// mixed kinds as JSON text; a missing value null), never one of the table's own names.
    #[test]
    fn per_episode_fields_become_typed_columns() {
        let row = |fields: Value| EpisodeRow {
            fields: fields.as_object().cloned().unwrap_or_default(),
            ..Default::default()
        };
        let rows = [
            row(json!({"id": "a", "n": 1, "x": 0.5, "ok": true, "mixed": 1, "length": 9})),
            row(json!({"id": "b", "n": 2, "x": 2, "mixed": "two"})),
        ];
        let columns: std::collections::BTreeMap<String, ArrayRef> =
            field_columns(&rows).into_iter().collect();
        assert_eq!(
            columns.keys().collect::<Vec<_>>(),
            ["id", "mixed", "n", "ok", "x"],
            "length is the table's own"
        );
        assert_eq!(columns["id"].data_type(), &DataType::Utf8);
        assert_eq!(columns["n"].data_type(), &DataType::Int64);
        assert_eq!(columns["x"].data_type(), &DataType::Float64);
        assert_eq!(columns["ok"].data_type(), &DataType::Boolean);
        assert_eq!(columns["ok"].null_count(), 1);
        let mixed = columns["mixed"]
            .as_any()
            .downcast_ref::<StringArray>()
            .expect("text");
        assert_eq!((mixed.value(0), mixed.value(1)), ("1", "\"two\""));
        assert!(free_field_name("episode_metadata/file_path") && !free_field_name("stats/a/min"));
    }

    #[test]
    fn a_stored_episode_reads_its_columns_leniently() {
        let columns = [
            ("episode_index", json!(3)),
            ("videos/observation.images.rgb/chunk_index", json!(0)),
            ("videos/observation.images.rgb/file_index", json!(2)),
            ("videos/observation.images.rgb/from_timestamp", json!(1.5)),
            ("videos/observation.images.rgb/to_timestamp", json!(2.0)),
            // A span lacking a column is no span.
            ("videos/cam/chunk_index", json!(0)),
            ("stats/observation.state/min", json!([0.0, 1.0])),
            ("stats/observation.state/count", json!([7])),
            ("stats/observation.state/max", json!("wrong")),
            (
                "surgvla/pixel_stats/observation.images.rgb",
                json!("{\"frames\": 4}"),
            ),
            ("surgvla/pixel_stats/cam", json!("not json")),
            ("surgvla/seed", json!(-1)),
            ("surgvla/task_id", json!("T1-1")),
            ("surgvla/level", json!("one")),
            ("surgvla/success", json!(true)),
        ];
        let episode = StoredEpisode::from_columns(columns);
        assert_eq!(
            episode.videos.get("observation.images.rgb"),
            Some(&VideoSpan {
                chunk: 0,
                file: 2,
                from_secs: 1.5,
                to_secs: 2.0
            })
        );
        assert!(!episode.videos.contains_key("cam"));
        let state = &episode.stats["observation.state"];
        assert_eq!(state.min, Some(StatValue::list([0.0, 1.0])));
        assert_eq!(state.count.as_ref().map(StatValue::flat), Some(vec![7.0]));
        assert_eq!(state.max, None);
        let exact: Value =
            serde_json::from_str(&episode.pixel_stats["observation.images.rgb"]).expect("json");
        assert_eq!(exact, json!({"frames": 4}));
        assert!(!episode.pixel_stats.contains_key("cam"));
        let p = &episode.provenance;
        assert_eq!(
            (p.seed, p.task_id.as_str(), p.level, p.success),
            (u64::MAX, "T1-1", 0, true)
        );
    }

    #[test]
    fn episode_stats_flatten_to_columns_by_depth() {
        let vector = StatValue::list([1.0, 2.0]);
        let image = StatValue::List(vec![StatValue::List(vec![StatValue::list([0.5])])]);
        let count = StatValue::list([4.0]);
        let column = stats_column(&[Some(&vector), None], "stats/a/min");
        assert_eq!(column.len(), 2);
        assert_eq!(
            column.data_type(),
            &DataType::List(Arc::new(Field::new_list_field(DataType::Float64, true)))
        );
        let nested = stats_column(&[Some(&image)], "stats/b/min");
        assert!(
            matches!(nested.data_type(), DataType::List(f) if matches!(f.data_type(), DataType::List(_)))
        );
        let counts = stats_column(&[Some(&count)], "stats/a/count");
        assert_eq!(
            counts.data_type(),
            &DataType::List(Arc::new(Field::new_list_field(DataType::Int64, true)))
        );
    }
}
