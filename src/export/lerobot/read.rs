//! Reading a LeRobot dataset back: [`LeRobotSource`] (an [`EpisodeSource`] of v3.0 and v2.1
//! datasets in image mode) and the low-level helpers the round-trip tests use. Interop is proven
//! with the real lerobot loader in `tests/interop/`.

use super::meta::{StatValue, StatsJson};
pub use super::rows::footer_problem;
use super::rows::{Next, Row, column, invalid, open_parquet_metadata, vector};
use super::table::StoredEpisode;
use crate::episode::{
    Dtype, EncodedFeature, EncodedFrame, Episode, EpisodeMeta, FeatureKind, FeatureSpec,
    ImageEncoding, MAX_OBJECTS, POSE_VALUES, PixelStats, StoredRows, VideoCodec,
};
use crate::export::bounded::read_json;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::paths::{self, Field};
use crate::export::source::EpisodeSource;
use crate::export::stats::ImageStats;
use crate::media::decode;
use crate::media::demux::VideoReader;
use crate::media::image::decode_png_sized;
use crate::media::tiff::decode_f32_tiff;
use arrow_array::{
    Array, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array, RecordBatch,
    StructArray,
};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::{Map, Value};
use std::fs::File;
use std::path::{Path, PathBuf};

/// One frame as stored.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredFrame {
    pub index: i64,
    pub episode_index: i64,
    pub frame_index: i64,
    pub task_index: i64,
    pub timestamp: f32,
    pub state: Vec<f32>,
    pub action: Vec<f32>,
    pub environment_state: Vec<f32>,
    /// Encoded image bytes by feature key.
    pub images: Vec<(String, Vec<u8>)>,
}

/// A parquet file's reader builder, its footer checked ([`footer_problem`]) first.
pub fn open_parquet(path: &Path) -> Result<ParquetRecordBatchReaderBuilder<File>, ExportError> {
    let (file, metadata) = open_parquet_metadata(path, false)?;
    Ok(ParquetRecordBatchReaderBuilder::new_with_metadata(
        file, metadata,
    ))
}

/// Reads every record batch of a parquet file.
pub fn read_parquet(path: &Path) -> Result<Vec<RecordBatch>, ExportError> {
    let parquet_error = ExportError::parquet(path);
    let reader = open_parquet(path)?.build().map_err(&parquet_error)?;
    reader
        .map(|batch| batch.map_err(ExportError::Arrow))
        .collect()
}

/// The value of a schema metadata key of a parquet file (e.g. "pandas").
pub fn schema_metadata(path: &Path, key: &str) -> Result<Option<String>, ExportError> {
    let builder = open_parquet(path)?;
    if let Some(value) = builder.schema().metadata().get(key) {
        return Ok(Some(value.clone()));
    }
    let pairs = builder.metadata().file_metadata().key_value_metadata();
    Ok(pairs.and_then(|kv| {
        kv.iter()
            .find(|p| p.key == key)
            .and_then(|p| p.value.clone())
    }))
}

/// The data files in path order.
pub fn data_files(root: &Path) -> Result<Vec<PathBuf>, ExportError> {
    parquet_files(&root.join("data"))
}

/// The parquet files in the chunk folders of `data` (`data/chunk-*/`, `meta/episodes/chunk-*/`)
/// in path order, temporary (hidden) files left out.
pub fn parquet_files(data: &Path) -> Result<Vec<PathBuf>, ExportError> {
    let mut files = Vec::new();
    let chunks = std::fs::read_dir(data).map_err(ExportError::io(data))?;
    for chunk in chunks {
        let chunk = chunk.map_err(ExportError::io(data))?.path();
        for file in std::fs::read_dir(&chunk).map_err(ExportError::io(&chunk))? {
            let file = file.map_err(ExportError::io(&chunk))?.path();
            if file.extension().is_some_and(|e| e == "parquet")
                && !file
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            {
                files.push(file);
            }
        }
    }
    files.sort();
    Ok(files)
}

/// Reads every frame of the dataset at `root`, in index order.
pub fn read_frames(root: &Path, image_keys: &[&str]) -> Result<Vec<StoredFrame>, ExportError> {
    let mut frames = Vec::new();
    for path in data_files(root)? {
        for batch in read_parquet(&path)? {
            let ints = |name| column::<Int64Array>(&batch, name, &path);
            let (index, episode, frame, task) = (
                ints("index")?,
                ints("episode_index")?,
                ints("frame_index")?,
                ints("task_index")?,
            );
            let timestamp = column::<Float32Array>(&batch, "timestamp", &path)?;
            let state = column::<FixedSizeListArray>(&batch, "observation.state", &path)?;
            let action = column::<FixedSizeListArray>(&batch, "action", &path)?;
            let environment =
                column::<FixedSizeListArray>(&batch, "observation.environment_state", &path)?;
            let images: Vec<(&str, &StructArray)> = image_keys
                .iter()
                .map(|k| column::<StructArray>(&batch, k, &path).map(|c| (*k, c)))
                .collect::<Result<_, _>>()?;
            for row in 0..batch.num_rows() {
                let mut encoded = Vec::new();
                for (key, images) in &images {
                    let bytes = images
                        .column_by_name("bytes")
                        .and_then(|c| c.as_any().downcast_ref::<BinaryArray>())
                        .ok_or_else(|| {
                            ExportError::InvalidEpisode(format!(
                                "{}: {key} has no bytes",
                                path.display()
                            ))
                        })?;
                    encoded.push((key.to_string(), bytes.value(row).to_vec()));
                }
                frames.push(StoredFrame {
                    index: index.value(row),
                    episode_index: episode.value(row),
                    frame_index: frame.value(row),
                    task_index: task.value(row),
                    timestamp: timestamp.value(row),
                    state: vector(state, row),
                    action: vector(action, row),
                    environment_state: vector(environment, row),
                    images: encoded,
                });
            }
        }
    }
    Ok(frames)
}

/// `meta/info.json`, typed (leniently: see [`super::meta`]).
pub(crate) fn read_info(path: &Path) -> Result<super::meta::InfoJson, ExportError> {
    let bytes = crate::export::bounded::read_metadata(path)?;
    let info = super::meta::InfoJson::parse(&bytes).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(problem) = info.template_problem() {
        return Err(invalid(path, problem));
    }
    Ok(info)
}

/// The features of info.json as surgvla's model knows them (defaults left out). Our roles
/// (RGB camera, depth, mask, 7-D state and action, object poses) go to the features our
/// metadata (`surgvla`, Null for another tool's dataset) names; every other float32, int64 or
/// image feature is [`FeatureKind::Other`] and travels unchanged.
fn features_of(
    info: &super::meta::InfoJson,
    surgvla: &Value,
    path: &Path,
    options: &crate::export::source::SourceOptions,
) -> Result<ReadFeatures, ExportError> {
    let (mut notes, mut omitted) = (Vec::new(), Vec::new());
    if info.features.is_none() {
        return Err(invalid(path, "no features object"));
    }
    let features = info.feature_list();
    let ours = !surgvla.is_null();
    let camera_key = surgvla["camera"]["key"].as_str();
    let depth_key = surgvla["depth"]["key"].as_str();
    let mut specs = Vec::new();
    for (name, f) in &features {
        if super::table::DEFAULT_COLUMNS.contains(&name.as_str()) {
            continue;
        }
        let shape: Vec<usize> = f.shape().to_vec();
        let names: Vec<String> = f
            .names
            .as_array()
            .map(|n| {
                n.iter()
                    .filter_map(|v| v.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default();
        let mut dtype = f.dtype();
        let named = |key: Option<&str>| ours && key == Some(name.as_str());
        // Video passes through as its encoded frames: the feature is an image feature whose
        // pixels are not in the steps.
        let video = if dtype == "video" {
            let codec_name = f.video_codec().unwrap_or_default();
            let Some(codec) = VideoCodec::from_name(codec_name) else {
                // surgvla's own camera is never left out (a conversion keeps it).
                if options.without.contains(name) && !named(camera_key) {
                    notes.push(format!(
                        "left out {name} (--without): video in codec {codec_name:?}, which surgvla does not decode"
                    ));
                    omitted.push(name.clone());
                    continue;
                }
                // A codec this build has no decoder for: the user's choice of input (exit 2).
                return Err(ExportError::InvalidOptions(format!(
                    "{}: {name} is video in codec {codec_name:?}; surgvla reads AV1 and H.264 video (no HEVC or VP9 decoder is built in): --without {name} leaves it out",
                    path.display()
                )));
            };
            dtype = "image";
            Some(codec)
        } else {
            None
        };
        if dtype == "float64" && shape.len() == 1 {
            let (read_as, note) = float64_read(name, options);
            dtype = read_as;
            notes.push(note);
        }
        let role = Role {
            ours,
            camera: named(camera_key),
            depth: named(depth_key),
        };
        let (dtype, kind) = role.of(name, dtype, &shape).ok_or_else(|| {
            invalid(
                path,
                format!(
                    "feature {name} ({dtype}, shape {shape:?}) is not one surgvla reads yet (float32 and int64 vectors, images, one string per frame)"
                ),
            )
        })?;
        specs.push(FeatureSpec {
            name: name.clone(),
            dtype,
            shape,
            names,
            kind,
            video,
            info: kept_info(kind, f.info.as_ref()),
        });
    }
    Ok(ReadFeatures {
        specs,
        notes,
        omitted,
    })
}

/// How a float64 vector feature is read (float64, or float32 with `--cast float32`), and the
/// note saying so.
fn float64_read(
    name: &str,
    options: &crate::export::source::SourceOptions,
) -> (&'static str, String) {
    if options.float64_as_float32 {
        let note = format!(
            "{name} is float64: read as float32 (--cast float32), rounded to about 7 significant digits"
        );
        return ("float32", note);
    }
    let note = format!(
        "{name} is float64, kept so (an RLDS output stores float32, as TFRecord does; --cast float32 narrows it everywhere)"
    );
    ("float64", note)
}

/// What [`features_of`] read: the features, the notes on how, the features left out.
struct ReadFeatures {
    specs: Vec<FeatureSpec>,
    notes: Vec<String>,
    omitted: Vec<String>,
}

/// Where another tool's LeRobot dataset came from, as a note for the card of its conversion:
/// its folder, layout version and the licence its own card (README.md) states, if any.
fn described(root: &Path, info: &super::meta::InfoJson) -> String {
    let version = info
        .codebase_version
        .as_deref()
        .unwrap_or("of no stated version");
    let licence = crate::export::bounded::read_capped(&root.join("README.md"), 1 << 20)
        .ok()
        .and_then(|card| {
            let card = String::from_utf8_lossy(&card);
            let front = card
                .strip_prefix("---\n")?
                .split("\n---")
                .next()?
                .to_string();
            front.lines().find_map(|line| {
                let value = line.strip_prefix("license:")?.trim();
                (!value.is_empty()).then(|| value.chars().take(100).collect::<String>())
            })
        });
    let name = root
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    match licence {
        Some(licence) => {
            format!("the input is the LeRobot dataset {name} ({version}), licence: {licence}")
        }
        None => format!(
            "the input is the LeRobot dataset {name} ({version}), whose card states no licence"
        ),
    }
}

/// What our metadata says of a feature: whether the dataset is surgvla's, and whether it names
/// the feature as its camera or its depth.
struct Role {
    ours: bool,
    camera: bool,
    depth: bool,
}

impl Role {
    /// The feature's dtype and role in surgvla's model, None for one it does not read.
    fn of(&self, name: &str, dtype: &str, shape: &[usize]) -> Option<(Dtype, FeatureKind)> {
        let ours = self.ours;
        Some(match dtype {
            "image" if self.camera && shape.last() == Some(&3) => (Dtype::Image, FeatureKind::Rgb),
            "image" if self.depth => (Dtype::Image, FeatureKind::Depth),
            "image" if ours && name == "observation.images.mask" => {
                (Dtype::Image, FeatureKind::Mask)
            }
            "float32" if ours && name == "observation.state" && shape == [7] => {
                (Dtype::Float32, FeatureKind::State)
            }
            "float32" if ours && name == "action" && shape == [7] => {
                (Dtype::Float32, FeatureKind::Action)
            }
            "float32"
                if ours
                    && name == "observation.environment_state"
                    && shape == [MAX_OBJECTS * POSE_VALUES] =>
            {
                (Dtype::Float32, FeatureKind::EnvironmentState)
            }
            "image" if shape.len() == 3 => (Dtype::Image, FeatureKind::Other),
            "float32" if shape.len() == 1 => (Dtype::Float32, FeatureKind::Other),
            "float64" if shape.len() == 1 => (Dtype::Float64, FeatureKind::Other),
            "int64" if shape.len() == 1 => (Dtype::Int64, FeatureKind::Other),
            "string" if shape == [1] => (Dtype::String, FeatureKind::Other),
            _ => return None,
        })
    }
}

/// What another tool's feature says of itself in its `info` (a pose's frame, a camera's
/// intrinsics, a depth map's unit, the encoder's settings), kept to travel with it; the keys a
/// writer derives from the stored data (the video's size, codec, rate, `has_audio`, `audio.*`)
/// are left out, to be written again.
fn kept_info(kind: FeatureKind, info: Option<&Map<String, Value>>) -> Map<String, Value> {
    // What the writer states of the video it writes; the encoder's settings another tool
    // recorded (`video.g`, `video.crf`) stay while the video is copied, and go where it is
    // decoded (`Decoded`).
    let derived = |key: &str| {
        matches!(
            key,
            "video.height"
                | "video.width"
                | "video.codec"
                | "video.pix_fmt"
                | "video.is_depth_map"
                | "video.fps"
                | "video.channels"
                | "has_audio"
        ) || key.starts_with("audio.")
    };
    match (kind, info) {
        (FeatureKind::Other, Some(info)) => (info.iter())
            .filter(|(key, _)| !derived(key))
            .map(|(key, value)| (key.clone(), value.clone()))
            .collect(),
        _ => Map::new(),
    }
}

/// One cell of an episodes table as JSON (numbers, strings, booleans, lists of them).
fn cell(column: &dyn Array, row: usize) -> Value {
    use arrow_array::{BooleanArray, ListArray, StringArray};
    let any = column.as_any();
    if column.is_null(row) {
        Value::Null
    } else if let Some(a) = any.downcast_ref::<Int64Array>() {
        Value::from(a.value(row))
    } else if let Some(a) = any.downcast_ref::<Float64Array>() {
        Value::from(a.value(row))
    } else if let Some(a) = any.downcast_ref::<Float32Array>() {
        Value::from(f64::from(a.value(row)))
    } else if let Some(a) = any.downcast_ref::<StringArray>() {
        Value::from(a.value(row))
    } else if let Some(a) = any.downcast_ref::<BooleanArray>() {
        Value::from(a.value(row))
    } else if let Some(a) = any.downcast_ref::<ListArray>() {
        let items = a.value(row);
        Value::Array((0..items.len()).map(|i| cell(items.as_ref(), i)).collect())
    } else if let Some(a) = any.downcast_ref::<FixedSizeListArray>() {
        let items = a.value(row);
        Value::Array((0..items.len()).map(|i| cell(items.as_ref(), i)).collect())
    } else {
        Value::Null
    }
}

/// The episodes metadata, one row at a time in index order, as the data reaches each episode:
/// v3.0's parquet files are read 64 rows at a time, so a reader holds a few rows, not every
/// episode's (memory flat in episodes); v2.1's jsonl files, whose stats lines may come in any
/// order, are read whole into the same shape.
enum EpisodeRows {
    Loaded(std::collections::VecDeque<StoredEpisode>),
    Parquet {
        files: std::vec::IntoIter<PathBuf>,
        open: Option<Box<OpenTable>>,
        /// Whether a whole row was asked for: files are then opened with every column a row
        /// uses ([`Wanted`]).
        whole: bool,
        /// The video features, whose LeRobot statistics a whole row reads.
        videos: Vec<String>,
    },
}

/// How much of an episode's row [`EpisodeRows::advance`] reads.
#[derive(Clone, Copy, Debug, PartialEq)]
enum RowPart {
    /// Nothing (the episode is skipped).
    Skip,
    /// What an episode's metadata needs: no statistics (what `skim` reads; the statistics
    /// columns are most of the table's bytes).
    Meta,
    /// Every column.
    Whole,
}

/// A file of v3.0's episodes table being read.
struct OpenTable {
    path: PathBuf,
    reader: parquet::arrow::arrow_reader::ParquetRecordBatchReader,
    /// The batch read last and its next row: each row is made a [`StoredEpisode`] only when
    /// asked for (a skipped episode's never is).
    batch: Option<(RecordBatch, usize)>,
    /// Rows of the file passed on so far.
    passed: usize,
}

/// The columns of an episodes table a reader decodes.
#[derive(Clone, Copy)]
enum Wanted<'a> {
    /// The metadata's (no statistics).
    Meta,
    /// The metadata's, surgvla's exact pixel statistics, and LeRobot's statistics of these
    /// features only (the video features: [`stored_pixel_stats`] is their one reader; every
    /// other feature's statistics are made from its values).
    Whole(&'a [String]),
}

impl Wanted<'_> {
    fn reads(self, column: &str) -> bool {
        match (self, column.strip_prefix(super::table::STATS)) {
            (Wanted::Meta, _) => !is_statistics_column(column),
            (Wanted::Whole(_), None) => true,
            (Wanted::Whole(summaries), Some(stat)) => (stat.rsplit_once('/'))
                .is_some_and(|(feature, _)| summaries.iter().any(|f| f == feature)),
        }
    }
}

impl OpenTable {
    /// `path` opened at row `offset`, with the columns `wanted`.
    fn open(path: PathBuf, wanted: Wanted<'_>, offset: usize) -> Result<Self, ExportError> {
        let builder = open_parquet(&path)?;
        let keep: Vec<usize> = (builder.schema().fields().iter().enumerate())
            .filter(|(_, f)| wanted.reads(f.name()))
            .map(|(i, _)| i)
            .collect();
        let mask = parquet::arrow::ProjectionMask::roots(builder.parquet_schema(), keep);
        let builder = builder.with_projection(mask);
        let reader = (builder.with_batch_size(64).with_offset(offset))
            .build()
            .map_err(ExportError::parquet(&path))?;
        Ok(OpenTable {
            path,
            reader,
            batch: None,
            passed: offset,
        })
    }
}

/// Whether an episodes table's column holds statistics (LeRobot's `stats/...`, surgvla's
/// pixel accumulators), which an episode's metadata does not need.
fn is_statistics_column(name: &str) -> bool {
    name.starts_with("stats/") || name.starts_with(super::table::PIXEL_STATS)
}

impl EpisodeRows {
    /// Opens the metadata; v3.0's files are checked to open as parquet now, so a damaged one
    /// stops a command before it writes anything.
    fn open(root: &Path, v21: bool, videos: Vec<String>) -> Result<Self, ExportError> {
        if v21 {
            return Ok(EpisodeRows::Loaded(episode_rows_v21(root)?.into()));
        }
        let files = parquet_files(&root.join("meta/episodes"))?;
        for path in &files {
            open_parquet(path)?;
        }
        Ok(EpisodeRows::Parquet {
            files: files.into_iter(),
            open: None,
            whole: false,
            videos,
        })
    }

    /// The per-episode values another tool's dataset carries in its episodes table (columns
    /// that are not LeRobot's or surgvla's), declared from the first episode's row (read on
    /// its own: the rows are read from the first on as they are asked for).
    fn declared_fields(&self) -> Result<Vec<crate::episode::EpisodeField>, ExportError> {
        let first = match self {
            EpisodeRows::Loaded(rows) => rows.front().cloned(),
            EpisodeRows::Parquet { files, .. } => {
                let mut first = None;
                // The first row of the first file holding one (a file may be empty).
                for path in files.as_slice() {
                    let mut table = OpenTable::open(path.clone(), Wanted::Meta, 0)?;
                    let batch = (table.reader.by_ref())
                        .map(|b| b.map_err(ExportError::Arrow))
                        .find(|b| b.as_ref().map_or(true, |b| b.num_rows() > 0))
                        .transpose()?;
                    first = batch.map(|b| stored_episode(&b, 0));
                    if first.is_some() {
                        break;
                    }
                }
                first
            }
        };
        let Some(first) = first else {
            return Ok(Vec::new());
        };
        Ok((first.fields.iter())
            .filter_map(|(key, value)| {
                let (dtype, len) = crate::episode::FieldDtype::of_json(value)?;
                Some(crate::episode::EpisodeField {
                    key: key.clone(),
                    dtype,
                    len,
                })
            })
            .collect())
    }

    /// The next episode's row, or None after the last.
    fn next_row(&mut self) -> Result<Option<StoredEpisode>, ExportError> {
        self.advance(RowPart::Whole)
    }

    /// The next episode's row without its statistics ([`RowPart::Meta`]).
    fn meta_row(&mut self) -> Result<Option<StoredEpisode>, ExportError> {
        self.advance(RowPart::Meta)
    }

    /// Passes over the next episode's row (a skipped episode's), without reading its cells.
    fn skip_row(&mut self) -> Result<(), ExportError> {
        self.advance(RowPart::Skip).map(|_| ())
    }

    /// The next episode's row, as much of it as `part` asks; None after the last (or when
    /// skipped). A file is read without its statistics columns until a whole row is asked
    /// for; from then on with every column a row uses ([`Wanted::Whole`]; the file being read
    /// opened again at its next row), so a reader that mixes the two opens a file at most
    /// twice.
    fn advance(&mut self, part: RowPart) -> Result<Option<StoredEpisode>, ExportError> {
        let (files, open, whole, videos) = match self {
            EpisodeRows::Loaded(rows) => return Ok(rows.pop_front()),
            EpisodeRows::Parquet {
                files,
                open,
                whole,
                videos,
            } => (files, open, whole, videos),
        };
        let wanted = |whole: bool| {
            if whole {
                Wanted::Whole(videos)
            } else {
                Wanted::Meta
            }
        };
        if part == RowPart::Whole && !*whole {
            *whole = true;
            if let Some(table) = open.take() {
                *open = Some(Box::new(OpenTable::open(
                    table.path,
                    wanted(true),
                    table.passed,
                )?));
            }
        }
        loop {
            let Some(table) = open.as_mut() else {
                let Some(path) = files.next() else {
                    return Ok(None);
                };
                *open = Some(Box::new(OpenTable::open(path, wanted(*whole), 0)?));
                continue;
            };
            if let Some((read, next)) = table.batch.as_mut().filter(|(b, n)| *n < b.num_rows()) {
                let row = *next;
                *next += 1;
                table.passed += 1;
                return Ok((part != RowPart::Skip).then(|| stored_episode(read, row)));
            }
            match table.reader.next() {
                Some(read) => table.batch = Some((read.map_err(ExportError::Arrow)?, 0)),
                None => *open = None,
            }
        }
    }
}

/// Row `row` of a batch of v3.0's episodes table. The statistics columns (most of its cells)
/// are read straight into [`StatValue`]s, not through JSON.
fn stored_episode(batch: &RecordBatch, row: usize) -> StoredEpisode {
    let schema = batch.schema();
    let is_stat = |name: &str| name.starts_with(super::table::STATS);
    let columns = (schema.fields().iter())
        .zip(batch.columns())
        .filter(|(field, _)| !is_stat(field.name()))
        .map(|(field, column)| (field.name().as_str(), cell(column.as_ref(), row)));
    let mut episode = StoredEpisode::from_columns(columns);
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        if is_stat(field.name()) {
            episode.set_stat(field.name(), stat_cell(column.as_ref(), row));
        }
    }
    episode
}

/// One cell of an episodes table's statistics column, as [`cell`] then `StatValue`'s
/// deserializer read it: numbers (a non-finite one as null), nulls, and lists of them; None
/// when it holds text or booleans (a statistic left out).
fn stat_cell(column: &dyn Array, row: usize) -> Option<StatValue> {
    use arrow_array::{ListArray, cast::AsArray};
    let any = column.as_any();
    if column.is_null(row) {
        return Some(StatValue::Null);
    }
    let items = |values: &dyn Array, range: std::ops::Range<usize>| {
        range
            .map(|i| stat_cell(values, i))
            .collect::<Option<Vec<_>>>()
    };
    if let Some(a) = any.downcast_ref::<Int64Array>() {
        Some(StatValue::Number(a.value(row).into()))
    } else if let Some(a) = any.downcast_ref::<Float64Array>() {
        Some(StatValue::number(a.value(row)))
    } else if let Some(a) = any.downcast_ref::<Float32Array>() {
        Some(StatValue::number(f64::from(a.value(row))))
    } else if let Some(a) = any.downcast_ref::<ListArray>() {
        let offsets = a.value_offsets();
        let (from, to) = (offsets[row] as usize, offsets[row + 1] as usize);
        items(a.values().as_ref(), from..to).map(StatValue::List)
    } else if let Some(a) = column.as_fixed_size_list_opt() {
        let len = a.value_length() as usize;
        items(a.values().as_ref(), row * len..(row + 1) * len).map(StatValue::List)
    } else if column.as_string_opt::<i32>().is_some() || column.as_boolean_opt().is_some() {
        None
    } else {
        // A type `cell` does not read, which it reads as null.
        Some(StatValue::Null)
    }
}

/// v2.1's episodes: `episodes.jsonl` in order, each joined with its `episodes_stats.jsonl` line
/// (by `episode_index`; the file may be absent).
fn episode_rows_v21(root: &Path) -> Result<Vec<StoredEpisode>, ExportError> {
    #[derive(serde::Deserialize)]
    struct StatsLine {
        episode_index: usize,
        stats: StatsJson,
    }
    fn lines<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Vec<T>, ExportError> {
        crate::export::bounded::lines(path)?
            .map(|line| {
                let (_, text) = line?;
                serde_json::from_str(&text).map_err(|source| ExportError::Json {
                    path: path.to_path_buf(),
                    source,
                })
            })
            .collect()
    }
    let episodes: Vec<serde_json::Map<String, Value>> = lines(&root.join("meta/episodes.jsonl"))?;
    let mut rows: Vec<StoredEpisode> = episodes
        .into_iter()
        .map(|line| StoredEpisode::from_columns(line.iter().map(|(k, v)| (k.as_str(), v.clone()))))
        .collect();
    let stats_path = root.join("meta/episodes_stats.jsonl");
    if stats_path.exists() {
        for line in lines::<StatsLine>(&stats_path)? {
            if let Some(row) = rows.get_mut(line.episode_index) {
                row.stats = line.stats;
            }
        }
    }
    Ok(rows)
}

/// Reads a LeRobot dataset (v3.0 or v2.1, image mode) episode by episode.
pub struct LeRobotSource {
    root: PathBuf,
    info: DatasetInfo,
    total_episodes: u64,
    tasks: Vec<String>,
    /// The episodes metadata, read in step with the data.
    episodes: EpisodeRows,
    v21: bool,
    chunks_size: u64,
    /// info.json's `video_path` template.
    video_path: String,
    /// The video file read last, kept open for the next episode in it.
    video: Option<(PathBuf, VideoReader)>,
    /// The data files' rows.
    data: super::rows::DataRows,
    /// Steps read past the end of the episode being assembled.
    pending: std::collections::VecDeque<Row>,
    /// Stored encodings a conversion will not copy (see [`EpisodeSource::drop_stored`]).
    unused_stored: Vec<ImageEncoding>,
    /// Whether episodes are read with their rows left in the data files where the writer can
    /// copy them ([`EpisodeSource::leave_rows_stored`]).
    leave_stored: bool,
    /// The row group the episode being taken was read from without its images, if its rows
    /// may be copied.
    stored: Option<super::copy::StoredGroup>,
    /// Episodes returned so far.
    returned: u64,
    /// Whether the end (or a count that disagrees with info.json) was reported.
    ended: bool,
}

/// The tasks table's instructions, in task-index order (v2.1: `meta/tasks.jsonl`).
fn read_tasks(root: &Path, v21: bool) -> Result<Vec<String>, ExportError> {
    Ok(if v21 {
        let path = root.join("meta/tasks.jsonl");
        let mut tasks = Vec::new();
        for line in crate::export::bounded::lines(&path)? {
            tasks.extend(super::meta::TaskLine::of(&line?.1).task);
        }
        tasks
    } else {
        let path = root.join("meta/tasks.parquet");
        let mut tasks = Vec::new();
        for batch in read_parquet(&path)? {
            let column = column::<arrow_array::StringArray>(&batch, "task", &path)?;
            tasks.extend(column.iter().map(|t| t.unwrap_or_default().to_string()));
        }
        tasks
    })
}

/// info.json's `splits`, unless they are the one `train` split of every episode (what a
/// dataset without splits says).
fn splits_of(info: &super::meta::InfoJson, episodes: u64) -> Vec<(String, std::ops::Range<u64>)> {
    let ranges = info.split_ranges();
    match &ranges[..] {
        [(name, range)] if name == "train" && *range == (0..episodes) => Vec::new(),
        _ => ranges,
    }
}

/// The pixel statistics an episodes-table row stores for video feature `key`: surgvla's exact
/// accumulator, else lerobot's per-episode summary.
fn stored_pixel_stats(row: &StoredEpisode, key: &str) -> Option<PixelStats> {
    match (row.pixel_stats.get(key), row.stats.get(key)) {
        // Kept as the text it is (one JSON value), parsed where it is merged.
        (Some(exact), _) => (serde_json::from_str::<serde::de::IgnoredAny>(exact).ok())
            .map(|_| PixelStats::Exact(exact.clone())),
        (None, Some(summary)) => serde_json::to_value(summary).ok().map(PixelStats::Summary),
        (None, None) => None,
    }
}

impl LeRobotSource {
    pub fn open(root: &Path) -> Result<Self, ExportError> {
        Self::open_with(root, &Default::default())
    }

    /// [`LeRobotSource::open`] with what `options` allow: another tool's float64 vectors
    /// read as float32 (a note says so; refused by name otherwise), video of a codec surgvla
    /// cannot decode left out when `options.without` names it (refused by name otherwise).
    pub fn open_with(
        root: &Path,
        options: &crate::export::source::SourceOptions,
    ) -> Result<Self, ExportError> {
        let info_path = root.join("meta/info.json");
        if !info_path.exists() {
            return Err(invalid(
                root,
                "no meta/info.json: not a LeRobot dataset, or an incomplete one",
            ));
        }
        let info_json = read_info(&info_path)?;
        let v21 = info_json.is_v21();
        let surgvla_path = root.join("meta/surgvla.json");
        let surgvla = if surgvla_path.exists() {
            read_json(&surgvla_path)?
        } else {
            Value::Null
        };
        let read = features_of(&info_json, &surgvla, &info_path, options)?;
        let (features, mut notes) = (read.specs, read.notes);
        // Video keys name folders: refused here, before any path is made of them.
        for feature in features.iter().filter(|f| f.video.is_some()) {
            paths::component(&feature.name).map_err(|problem| ExportError::UnsafeName {
                path: info_path.clone(),
                what: "video feature",
                name: feature.name.clone(),
                problem,
            })?;
        }
        let tasks = read_tasks(root, v21)?;
        let mut info = DatasetInfo::from_surgvla_json(
            &surgvla,
            info_json.fps.as_ref().and_then(|f| f.as_u64()).unwrap_or(0) as u32,
            info_json.robot_type.as_deref().unwrap_or_default(),
            features,
        );
        if !info.is_ours() {
            notes.insert(0, described(root, &info_json));
        }
        info.notes = notes;
        info.omitted = read.omitted;
        info.carried_keys = info_json.other.clone();
        info.splits = splits_of(&info_json, info_json.total_episodes.unwrap_or(0));
        let videos = (info.features.iter().filter(|f| f.video.is_some()))
            .map(|f| f.name.clone())
            .collect();
        let episodes = EpisodeRows::open(root, v21, videos)?;
        info.episode_fields = episodes.declared_fields()?;
        Ok(LeRobotSource {
            root: root.to_path_buf(),
            total_episodes: info_json.total_episodes.unwrap_or(0),
            episodes,
            v21,
            chunks_size: info_json.chunks_size.unwrap_or(1000).max(1),
            video_path: info_json
                .video_path
                .as_deref()
                .unwrap_or(if v21 {
                    "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
                } else {
                    "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
                })
                .to_string(),
            video: None,
            tasks,
            data: super::rows::DataRows::new(data_files(root)?),
            pending: Default::default(),
            unused_stored: Vec::new(),
            leave_stored: false,
            stored: None,
            returned: 0,
            ended: false,
            info,
        })
    }

    /// Episode `index`'s file of video feature `key` (relative, from info.json's template) and
    /// its span there (v2.1: the whole file).
    fn video_file(
        &self,
        key: &str,
        index: u64,
        row: Option<&StoredEpisode>,
    ) -> Result<(std::path::PathBuf, Option<(f64, f64)>), ExportError> {
        let stored_span = row.and_then(|r| r.videos.get(key)).copied();
        let (fields, span) = if self.v21 {
            let fields = [
                ("video_key", Field::Name(key)),
                ("episode_chunk", Field::Index(index / self.chunks_size)),
                ("episode_index", Field::Index(index)),
            ];
            (fields, None)
        } else {
            let Some(span) = stored_span else {
                return Err(invalid(
                    &self.root.join("meta/episodes"),
                    format!("episode {index} lacks its videos/{key}/... columns"),
                ));
            };
            let fields = [
                ("video_key", Field::Name(key)),
                ("chunk_index", Field::Index(span.chunk)),
                ("file_index", Field::Index(span.file)),
            ];
            (fields, Some((span.from_secs, span.to_secs)))
        };
        let relative =
            paths::fill(&self.video_path, &fields).map_err(|problem| ExportError::UnsafeName {
                path: self.root.join("meta/info.json"),
                what: "video_path template",
                name: self.video_path.clone(),
                problem,
            })?;
        Ok((relative, span))
    }

    /// An episode's samples of the video feature `feature`, with the statistics its metadata
    /// carries: for each row, the picture lerobot would give it (the nearest presentation time
    /// to the row's `timestamp`, plus the episode's `from_timestamp` in v3.0, within 1e-4 s).
    /// Samples that are one per row in order are marked copyable (`shown` None).
    fn video_frames(
        &mut self,
        feature: &FeatureSpec,
        index: u64,
        row: Option<&StoredEpisode>,
        timestamps: &[Option<f64>],
    ) -> Result<EncodedFeature, ExportError> {
        let key = feature.name.as_str();
        let steps = timestamps.len();
        let pixel_stats = row.and_then(|r| stored_pixel_stats(r, key));
        let (relative, span) = self.video_file(key, index, row)?;
        let path = self.root.join(relative);
        if self.video.as_ref().is_none_or(|(open, _)| *open != path) {
            self.video = Some((path.clone(), VideoReader::open(&path)?));
        }
        let Some((_, reader)) = self.video.as_mut() else {
            return Err(ExportError::Internal("no open video".into()));
        };
        if Some(reader.codec) != feature.video {
            return Err(invalid(
                &path,
                format!(
                    "holds {} video where info.json says {key} is {}",
                    reader.codec.name(),
                    feature.video.map_or("", VideoCodec::name)
                ),
            ));
        }
        let (from, to) = span.unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
        let decodable = reader.decodable(from, to)?;
        let offset = span.map_or(0.0, |(from, _)| from);
        let queries = timestamps
            .iter()
            .enumerate()
            .map(|(row, t)| {
                t.map(|t| t + offset).ok_or_else(|| {
                    invalid(
                        &self.root.join("data"),
                        format!(
                            "episode {index} row {row} has no timestamp to pick its {key} frame by"
                        ),
                    )
                })
            })
            .collect::<Result<Vec<f64>, _>>()?;
        let shown = decode::nearest_frames(
            &decodable.picture_secs,
            &queries,
            decode::FRAME_TOLERANCE_SECS,
        )
        .map_err(|miss| {
            invalid(
                &path,
                format!(
                    "no frame of episode {index} lies within {} s of row {}'s time {:.6} s (the nearest is {:.6} s away; the span holds {} frames for {steps} rows)",
                    decode::FRAME_TOLERANCE_SECS,
                    miss.query,
                    miss.query_secs,
                    miss.distance_secs,
                    decodable.picture_secs.len()
                ),
            )
        })?;
        let copyable = !reader.reorders
            && decodable.samples.len() == steps
            && decodable.samples.first().is_some_and(|f| f.keyframe)
            && shown.iter().enumerate().all(|(i, p)| i == *p);
        Ok(EncodedFeature {
            feature: key.to_string(),
            encoding: ImageEncoding::Video(reader.codec),
            frames: decodable.samples,
            pixel_stats,
            shown: (!copyable).then_some(shown),
            file: Some(path),
        })
    }
}

/// The image features surgvla decodes into steps (RGB, mask, depth), in feature order: a
/// [`Row`] holds their encoded bytes.
pub(super) fn step_images(info: &DatasetInfo) -> impl Iterator<Item = &FeatureSpec> {
    info.features
        .iter()
        .filter(|f| f.in_steps() && f.dtype == Dtype::Image && f.kind != FeatureKind::Other)
}

/// Decodes a row's images into its step (frame `frame` of episode `episode`); returns the
/// encoded bytes of those not of an `unused` encoding, which the episode keeps beside the
/// pixels (in [`step_images`] order).
fn decode_row(
    row: &mut Row,
    info: &DatasetInfo,
    unused: &[ImageEncoding],
    frame: usize,
) -> Result<Vec<Vec<u8>>, ExportError> {
    let (width, height) = info.image_size();
    let mut kept = Vec::new();
    let images = std::mem::take(&mut row.images);
    for (feature, encoded) in step_images(info).zip(images) {
        let name = &feature.name;
        let step = &mut row.step;
        let bad = |e: String| {
            invalid(
                &row.file,
                format!("{name} of episode {} frame {frame}: {e}", row.episode),
            )
        };
        match feature.kind {
            FeatureKind::Depth => {
                let (w, h, depth) =
                    decode_f32_tiff(&encoded).ok_or_else(|| bad("not a float32 TIFF".into()))?;
                if (w as usize, h as usize) != (width, height) {
                    return Err(bad(format!("a {w}x{h} depth image")));
                }
                step.depth_m = depth;
            }
            kind => {
                let (w, h, channels, pixels) =
                    decode_png_sized(&encoded, Some((width, height))).map_err(bad)?;
                let wanted = if kind == FeatureKind::Rgb { 3 } else { 1 };
                if (w as usize, h as usize, channels) != (width, height, wanted) {
                    return Err(bad(format!("a {w}x{h} image with {channels} channels")));
                }
                if kind == FeatureKind::Rgb {
                    step.rgb = pixels;
                } else {
                    step.mask = pixels;
                }
            }
        }
        if !unused.contains(&ImageEncoding::of_kind(feature.kind)) {
            kept.push(encoded);
        }
    }
    Ok(kept)
}

impl LeRobotSource {
    /// After the last row: None, once the episodes read agree with info.json's total.
    fn end<T>(&mut self) -> Option<Result<T, ExportError>> {
        if self.ended || self.returned == self.total_episodes {
            self.ended = true;
            return None;
        }
        self.ended = true;
        Some(Err(invalid(
            &self.root.join("meta/info.json"),
            format!(
                "says the dataset holds {} episodes; its data files hold {}",
                self.total_episodes, self.returned
            ),
        )))
    }
}

/// An episode's index, its rows and its row of the episodes table (see
/// [`LeRobotSource::take_episode`]).
type TakenEpisode = (i64, Vec<Row>, Option<StoredEpisode>);

/// How much of an episode's rows [`LeRobotSource::take_episode`] reads.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Take {
    /// Every column.
    Whole,
    /// Every column but the images.
    Light,
    /// Every column but the images when a row group holds the whole episode (the group kept
    /// in [`LeRobotSource::stored`] for copying), else every column.
    Stored,
    /// Nothing the row groups' statistics can tell without reading (no rows returned).
    Skip,
}

impl LeRobotSource {
    /// The next episode's index, its rows (images still encoded unless `take` leaves them
    /// out; each its task) and its row of the episodes table; None after the last.
    fn take_episode(&mut self, take: Take) -> Option<Result<TakenEpisode, ExportError>> {
        if self.ended {
            return None;
        }
        match self.take_rows(take) {
            Ok((Some(index), rows)) => self.taken(index, rows, take),
            Ok((None, _)) => self.end(),
            Err(error) => {
                self.ended = true;
                Some(Err(error))
            }
        }
    }

    /// The next episode's index (None: the data is done) and its rows.
    fn take_rows(&mut self, take: Take) -> Result<(Option<i64>, Vec<Row>), ExportError> {
        self.stored = None;
        let mut rows = Vec::new();
        let mut current: Option<i64> = None;
        loop {
            if let Some(Row { episode, .. }) = self.pending.front() {
                if current.is_some_and(|e| e != *episode) {
                    break;
                }
                current = Some(*episode);
                if let Some(row) = self.pending.pop_front() {
                    rows.push(row);
                }
                continue;
            }
            match self.data.next()? {
                None => break,
                // A group of one episode, the statistics say: passed over or read lightly.
                Some(Next::Episode(episode)) if take != Take::Whole => {
                    if current.is_some_and(|e| e != episode) {
                        break;
                    }
                    if take == Take::Skip {
                        current = Some(episode);
                        self.data.skip_group();
                    } else if take == Take::Stored && current.is_some() {
                        // The episode goes on in another group: read whole (the rows of the
                        // first, read without images, get them back in `stored_episode`).
                        let group = self.data.read_group(&self.info, true)?;
                        self.pending.extend(group);
                    } else {
                        if take == Take::Stored {
                            self.stored = self.data.stored_group();
                        }
                        let images = take == Take::Stored && self.stored.is_none();
                        let group = self.data.read_group(&self.info, images)?;
                        self.pending.extend(group);
                    }
                }
                Some(_) => {
                    if let Some(batch) = self.data.read_batch(&self.info)? {
                        self.pending.extend(batch);
                    }
                }
            }
        }
        Ok((current, rows))
    }

    /// Episode `index` taken: checked to come next, with its row of the episodes table (not
    /// read when `take` skips the episode).
    fn taken(
        &mut self,
        index: i64,
        rows: Vec<Row>,
        take: Take,
    ) -> Option<Result<TakenEpisode, ExportError>> {
        if index < 0 || index as u64 != self.returned {
            self.ended = true;
            return Some(Err(invalid(
                &self.root.join("data"),
                format!(
                    "the data files hold episode {index} where episode {} comes next (a data file missing or out of order?)",
                    self.returned
                ),
            )));
        }
        self.returned += 1;
        // The episodes table's rows come in the data's order: this episode's is the next.
        let row = match take {
            Take::Skip => self.episodes.skip_row().map(|()| None),
            Take::Light => self.episodes.meta_row(),
            Take::Whole | Take::Stored => self.episodes.next_row(),
        };
        match row {
            Ok(row) => Some(Ok((index, rows, row))),
            Err(error) => {
                self.ended = true;
                Some(Err(error))
            }
        }
    }
}

impl Iterator for LeRobotSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let take = if self.leave_stored {
            Take::Stored
        } else {
            Take::Whole
        };
        let (index, mut rows, row) = match self.take_episode(take)? {
            Ok(taken) => taken,
            Err(error) => return Some(Err(error)),
        };
        let (image_stats, stored_rows) = match self.stored_rows(&mut rows, row.as_ref()) {
            Ok(taken) => taken,
            Err(error) => {
                self.ended = true;
                return Some(Err(error));
            }
        };
        let row_tasks: Vec<i64> = rows.iter().map(|r| r.task).collect();
        let stored_keys: Vec<(String, FeatureKind)> = step_images(&self.info)
            .filter(|f| !self.unused_stored.contains(&ImageEncoding::of_kind(f.kind)))
            .filter(|f| stored_rows.as_ref().is_none_or(|s| !s.holds_pixels(f)))
            .map(|f| (f.name.clone(), f.kind))
            .collect();
        let mut stored: Vec<Vec<EncodedFrame>> = vec![Vec::new(); stored_keys.len()];
        let mut steps = Vec::with_capacity(rows.len());
        let mut timestamps = Vec::with_capacity(rows.len());
        for (frame, mut data_row) in rows.into_iter().enumerate() {
            let kept = match decode_row(&mut data_row, &self.info, &self.unused_stored, frame) {
                Ok(kept) => kept,
                Err(error) => {
                    self.ended = true;
                    return Some(Err(error));
                }
            };
            for (frames, data) in stored.iter_mut().zip(kept) {
                frames.push(EncodedFrame {
                    data,
                    keyframe: true,
                });
            }
            steps.push(data_row.step);
            timestamps.push(data_row.timestamp_secs);
        }
        let mut encoded: Vec<EncodedFeature> = stored_keys
            .into_iter()
            .zip(stored)
            .map(|((feature, kind), frames)| EncodedFeature {
                encoding: ImageEncoding::of_kind(kind),
                feature,
                frames,
                pixel_stats: None,
                shown: None,
                file: None,
            })
            .collect();
        let videos: Vec<FeatureSpec> = self
            .info
            .features
            .iter()
            .filter(|f| !f.in_steps())
            .cloned()
            .collect();
        for feature in &videos {
            match self.video_frames(feature, index as u64, row.as_ref(), &timestamps) {
                Ok(frames) => encoded.push(frames),
                Err(error) => return Some(Err(error)),
            }
        }
        let meta = match self.meta(index, &row_tasks, row.as_ref()) {
            Ok(meta) => meta,
            Err(error) => return Some(Err(error)),
        };
        Some(Ok(Episode {
            encoded,
            image_stats,
            stored_rows,
            meta,
            steps,
        }))
    }
}

/// Exact pixel statistics by image feature.
type ImageStatsOf = Vec<(String, PixelStats)>;

/// The exact pixel statistics the episodes-table row `row` stores for the image features in
/// the steps (surgvla's datasets), those of the shape the feature's statistics have.
fn exact_image_stats(row: &StoredEpisode, info: &DatasetInfo) -> Vec<(String, PixelStats)> {
    step_images(info)
        .filter_map(|f| {
            let exact = row.pixel_stats.get(&f.name)?;
            let parsed = serde_json::from_str::<ImageStats>(exact).ok()?;
            parsed
                .fits(f)
                .then(|| (f.name.clone(), PixelStats::Exact(exact.clone())))
        })
        .collect()
}

impl LeRobotSource {
    /// The episode just taken's images' exact statistics (from its episodes-table row `row`),
    /// and its rows left in their data file for copying, when one whole row group holds them
    /// and every image has exact statistics (so that nothing needs the pixels); otherwise the
    /// images its first rows were read without, read now.
    fn stored_rows(
        &mut self,
        rows: &mut [Row],
        row: Option<&StoredEpisode>,
    ) -> Result<(ImageStatsOf, Option<StoredRows>), ExportError> {
        let image_stats = row.map_or_else(Vec::new, |row| exact_image_stats(row, &self.info));
        let stored = self.stored_rows_of(rows, &image_stats)?;
        Ok((image_stats, stored))
    }

    /// [`LeRobotSource::stored_rows`] given the statistics.
    fn stored_rows_of(
        &mut self,
        rows: &mut [Row],
        image_stats: &[(String, PixelStats)],
    ) -> Result<Option<StoredRows>, ExportError> {
        let Some(group) = self.stored.take() else {
            return Ok(None);
        };
        let all_stats =
            step_images(&self.info).all(|f| image_stats.iter().any(|(name, _)| *name == f.name));
        if group.rows() == rows.len() as u64 && all_stats {
            let columns = (self.info.features.iter())
                .filter(|f| f.in_steps())
                .map(|f| (f.name.clone(), f.name.clone()))
                .collect();
            return Ok(Some(StoredRows {
                columns,
                handle: std::sync::Arc::new(group),
            }));
        }
        let images = super::rows::stored_images(&group, &self.info)?;
        for (row, images) in rows.iter_mut().zip(images) {
            row.images = images;
        }
        Ok(None)
    }
}

impl LeRobotSource {
    /// Episode `index`'s metadata: its rows' tasks and its row of the episodes table.
    fn meta(
        &self,
        index: i64,
        row_tasks: &[i64],
        row: Option<&StoredEpisode>,
    ) -> Result<EpisodeMeta, ExportError> {
        let provenance = row.map(|e| e.provenance.clone()).unwrap_or_default();
        let fields = row.map(|e| e.fields.clone()).unwrap_or_default();
        let (instruction, task_changes) = self.instructions(index, row_tasks)?;
        Ok(EpisodeMeta {
            index: index as u64,
            task_code: provenance.task_id,
            task_name: String::new(),
            level: provenance.level,
            instruction,
            seed: provenance.seed,
            attempts: provenance.attempts,
            success: provenance.success,
            task_changes,
            fields,
        })
    }

    /// Episode `index`'s instruction and its changes, from its rows' task indices.
    fn instructions(
        &self,
        index: i64,
        row_tasks: &[i64],
    ) -> Result<(String, Vec<crate::episode::TaskChange>), ExportError> {
        let mut instructions = Vec::with_capacity(row_tasks.len());
        for &task in row_tasks {
            let Some(instruction) = usize::try_from(task).ok().and_then(|t| self.tasks.get(t))
            else {
                return Err(invalid(
                    &self.root,
                    format!("episode {index} names task_index {task}, which the tasks table lacks"),
                ));
            };
            instructions.push(instruction.as_str());
        }
        let changes = EpisodeMeta::changes_of(instructions.iter().copied());
        let first = instructions.first().copied().unwrap_or_default();
        Ok((first.to_string(), changes))
    }
}

impl LeRobotSource {
    /// The next episode skimmed from its row groups' statistics alone, when each of its groups
    /// holds it alone and says its one task ([`super::rows::DataRows::counted_groups`]).
    fn counted(&mut self) -> Option<Result<crate::export::source::Skimmed, ExportError>> {
        if self.ended || !self.pending.is_empty() {
            return None;
        }
        let index = match self.data.next() {
            Ok(Some(super::rows::Next::Episode(index))) => index,
            Ok(_) => return None,
            // A data file that does not open is named now: reading on would pass over it.
            Err(error) => {
                self.ended = true;
                return Some(Err(error));
            }
        };
        let groups = self.data.counted_groups(index)?;
        for _ in &groups {
            self.data.skip_group();
        }
        let tasks: Vec<i64> = (groups.iter())
            .flat_map(|(rows, task)| std::iter::repeat_n(*task, *rows as usize))
            .collect();
        let taken = self.taken(index, Vec::new(), Take::Light)?;
        Some(self.skimmed(taken.map(|(index, _, row)| (index, tasks, row))))
    }

    /// An episode taken with its rows' tasks, skimmed; an error ends the reading.
    fn skimmed(
        &mut self,
        taken: Result<(i64, Vec<i64>, Option<StoredEpisode>), ExportError>,
    ) -> Result<crate::export::source::Skimmed, ExportError> {
        let skimmed = taken.and_then(|(index, tasks, row)| {
            Ok(crate::export::source::Skimmed {
                meta: self.meta(index, &tasks, row.as_ref())?,
                steps: tasks.len() as u64,
            })
        });
        if skimmed.is_err() {
            self.ended = true;
        }
        skimmed
    }
}

impl EpisodeSource for LeRobotSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn drop_stored(&mut self, unused: &[ImageEncoding]) {
        self.unused_stored = unused.to_vec();
    }

    /// The data files read ahead only where the episodes taken lie (video files are small
    /// beside them, and read ahead as before).
    fn taking_only(&mut self, episodes: std::sync::Arc<std::collections::BTreeSet<u64>>) {
        self.data.taking_only(episodes);
    }

    /// Rows are left stored only where every image in the parquet is surgvla's (RGB, depth,
    /// mask): another tool's images carry statistics only their pixels give.
    fn leave_rows_stored(&mut self) {
        let parquet: Vec<FeatureSpec> = (self.info.features.iter())
            .filter(|f| f.in_steps())
            .cloned()
            .collect();
        if (parquet.iter()).all(|f| f.dtype != Dtype::Image || f.kind != FeatureKind::Other) {
            self.leave_stored = true;
            self.data.leave_stored(super::table::frame_schema(&parquet));
        }
    }

    fn len(&self) -> u64 {
        self.total_episodes
    }

    /// The episode's rows are read, but its images are never decoded nor its video read.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.take_episode(Take::Skip).map(|taken| taken.map(|_| ()))
    }

    /// The episode's tasks and length from its row groups' statistics where they say them
    /// (nothing read), else from its rows read without their images (nor its video).
    fn skim(&mut self) -> Option<Result<crate::export::source::Skimmed, ExportError>> {
        if let Some(counted) = self.counted() {
            return Some(counted);
        }
        let taken = self.take_episode(Take::Light)?;
        let tasks = |rows: Vec<Row>| rows.iter().map(|r| r.task).collect();
        Some(self.skimmed(taken.map(|(index, rows, row)| (index, tasks(rows), row))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A row's metadata reads no statistics; a whole row reads surgvla's exact pixel
    /// statistics and LeRobot's statistics of the video features only (a feature's name may
    /// hold a slash; a feature whose name starts another's is not it).
    #[test]
    fn a_whole_row_reads_the_statistics_of_the_video_features_only() {
        let videos = [
            "observation.images.left".to_string(),
            "cam/wrist".to_string(),
        ];
        let columns = [
            ("episode_index", true, true),
            ("videos/observation.images.left/from_timestamp", true, true),
            ("surgvla/pixel_stats/observation.images.depth", false, true),
            ("stats/observation.images.left/mean", false, true),
            ("stats/cam/wrist/q01", false, true),
            ("stats/observation.images.depth/mean", false, false),
            ("stats/observation.state/std", false, false),
            ("stats/observation.images.left2/mean", false, false),
            ("stats/cam/q01", false, false),
            ("stats/", false, false),
        ];
        for (column, meta, whole) in columns {
            assert_eq!(Wanted::Meta.reads(column), meta, "{column} in the metadata");
            assert_eq!(
                Wanted::Whole(&videos).reads(column),
                whole,
                "{column} in a row"
            );
        }
    }

    /// A statistics cell read straight into a `StatValue` is what reading it as JSON and
    /// deserializing gives, for every type an episodes table may hold (numbers of each kind,
    /// non-finite ones, nulls at each depth, nested and fixed-size lists, sliced arrays, text,
    /// booleans, a type neither reads), on seeded random values.
    #[test]
    fn statistics_cells_read_straight_as_through_json() {
        use arrow_array::builder::{Float64Builder, ListBuilder};
        use arrow_array::{ArrayRef, BooleanArray, Int32Array, ListArray, StringArray};
        let mut rng = crate::rng::SplitMix64::new(4);
        let mut value = || match rng.next_u64() % 8 {
            0 => None,
            1 => Some(f64::NAN),
            2 => Some(f64::INFINITY),
            _ => Some((rng.next_u64() % 2001) as f64 / 8.0 - 125.0),
        };
        // Lists of 0-3 numbers (nulls among them, and null lists), then (C, 1, 1) lists of them.
        let mut flat = ListBuilder::new(Float64Builder::new());
        let mut nested = ListBuilder::new(ListBuilder::new(Float64Builder::new()));
        for row in 0..64 {
            for _ in 0..row % 4 {
                flat.values().append_option(value());
                nested.values().values().append_option(value());
                nested.values().append(true);
            }
            flat.append(row % 9 != 5);
            nested.append(row % 11 != 7);
        }
        let floats: Vec<Option<f64>> = (0..64).map(|_| value()).collect();
        let fixed = arrow_array::FixedSizeListArray::try_new(
            Arc::new(arrow_schema::Field::new(
                "item",
                arrow_schema::DataType::Float32,
                true,
            )),
            2,
            Arc::new(Float32Array::from_iter(
                floats.iter().map(|v| v.map(|v| v as f32)),
            )),
            None,
        )
        .expect("fixed");
        let columns: Vec<ArrayRef> = vec![
            Arc::new(Float64Array::from(floats.clone())),
            Arc::new(Int64Array::from_iter(
                (0..64).map(|i| Some(i * 977 - 30_000)),
            )),
            Arc::new(flat.finish()),
            Arc::new(flat_slice(&nested.finish())),
            Arc::new(fixed.slice(3, 20)),
            Arc::new(StringArray::from_iter((0..64).map(|i| Some(i.to_string())))),
            Arc::new(BooleanArray::from_iter((0..64).map(|i| Some(i % 2 == 0)))),
            Arc::new(Int32Array::from_iter((0..64).map(Some))),
            Arc::new(ListArray::from_iter_primitive::<
                arrow_array::types::Int32Type,
                _,
                _,
            >((0..64).map(|i| Some(vec![Some(i)])))),
        ];
        for column in &columns {
            for row in 0..column.len() {
                let through_json = serde_json::from_value::<StatValue>(cell(column.as_ref(), row));
                assert_eq!(
                    stat_cell(column.as_ref(), row),
                    through_json.ok(),
                    "{:?} row {row}",
                    column.data_type()
                );
            }
        }
    }

    /// `list` from its fifth row on (an array whose offsets do not start at 0).
    fn flat_slice(list: &arrow_array::ListArray) -> arrow_array::ListArray {
        list.slice(5, list.len() - 5)
    }

    /// A real footer, and the size of its file.
    fn footer() -> (parquet::file::metadata::ParquetMetaData, u64) {
        let column: arrow_array::ArrayRef = Arc::new(arrow_array::Int64Array::from(vec![1, 2, 3]));
        let batch = RecordBatch::try_from_iter([("index", column)]).expect("batch");
        let mut bytes = Vec::new();
        let mut writer =
            parquet::arrow::ArrowWriter::try_new(&mut bytes, batch.schema(), None).expect("writer");
        writer.write(&batch).expect("write");
        writer.close().expect("close");
        let size = bytes.len() as u64;
        // One file per call: tests run in parallel.
        static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!(
            "surgvla-footer-{}-{call}.parquet",
            std::process::id()
        ));
        std::fs::write(&path, bytes).expect("write");
        let builder = open_parquet(&path).expect("footer");
        std::fs::remove_file(&path).ok();
        (builder.metadata().as_ref().clone(), size)
    }

    #[test]
    fn forged_footers_are_refused_before_reading() {
        let (metadata, size) = footer();
        assert_eq!(footer_problem(&metadata, size), None);
        // Column chunks beyond the file's end (a footer from a larger file, or a cut one).
        let beyond = footer_problem(&metadata, 10).expect("refused");
        assert!(beyond.contains("beyond the file's 10"), "{beyond}");
        // 10^12 rows in a few hundred bytes.
        let group = metadata.row_group(0).clone();
        let forged = group
            .into_builder()
            .set_num_rows(1_000_000_000_000)
            .build()
            .expect("row group");
        let forged = metadata
            .clone()
            .into_builder()
            .set_row_groups(vec![forged])
            .build();
        let claims = footer_problem(&forged, size).expect("refused");
        assert!(claims.contains("claims 1000000000000 rows"), "{claims}");
        let negative = metadata
            .row_group(0)
            .clone()
            .into_builder()
            .set_num_rows(-1)
            .build()
            .expect("row group");
        let original = metadata.clone();
        let negative = metadata
            .into_builder()
            .set_row_groups(vec![negative])
            .build();
        assert!(
            footer_problem(&negative, size)
                .expect("refused")
                .contains("claims -1 rows")
        );
        // The file's own row count, forged alone: every command refuses it alike.
        for stated in [1_000_000_000_000, -1, i64::MAX, 2] {
            let file = original.file_metadata();
            let forged = parquet::file::metadata::FileMetaData::new(
                file.version(),
                stated,
                file.created_by().map(String::from),
                file.key_value_metadata().cloned(),
                file.schema_descr_ptr(),
                file.column_orders().cloned(),
            );
            let forged = parquet::file::metadata::ParquetMetaData::new(
                forged,
                original.row_groups().to_vec(),
            );
            let problem = footer_problem(&forged, size).expect("refused");
            assert!(
                problem.contains(&format!("claims {stated} rows")),
                "{problem}"
            );
        }
    }

    /// A footer with one column chunk changed by `edit`.
    fn with_column(
        metadata: &parquet::file::metadata::ParquetMetaData,
        edit: impl FnOnce(
            parquet::file::metadata::ColumnChunkMetaDataBuilder,
        ) -> parquet::file::metadata::ColumnChunkMetaDataBuilder,
    ) -> parquet::file::metadata::ParquetMetaData {
        let group = metadata.row_group(0).clone();
        let column = edit(group.column(0).clone().into_builder())
            .build()
            .expect("column");
        let group = group
            .into_builder()
            .set_column_metadata(vec![column])
            .build()
            .expect("row group");
        metadata
            .clone()
            .into_builder()
            .set_row_groups(vec![group])
            .build()
    }

    /// Negative sizes and offsets, on which the parquet crate asserts (a panic in every
    /// command before), and row groups sharing their bytes (20,000 of them made every command
    /// run past a minute) are refused from the footer alone.
    #[test]
    fn column_chunks_at_negative_offsets_or_sharing_bytes_are_refused() {
        let (metadata, size) = footer();
        let negative_size = with_column(&metadata, |c| c.set_total_compressed_size(-5));
        let problem = footer_problem(&negative_size, size).expect("refused");
        assert!(problem.contains("..+-5"), "{problem}");
        let negative_offset = with_column(&metadata, |c| c.set_data_page_offset(-4));
        assert!(footer_problem(&negative_offset, size).is_some());
        let group = metadata.row_group(0).clone();
        let shared = metadata
            .clone()
            .into_builder()
            .set_row_groups(vec![group; 20_000])
            .build();
        let problem = footer_problem(&shared, size).expect("refused");
        assert!(problem.contains("chunks that share bytes"), "{problem}");
    }
}
