//! The rows of one row group of a LeRobot data file: columns against the declared features,
//! indices, timestamps, task indices, finite numbers, decodable images of the declared size and
//! channels, and the semantic checks of our datasets per episode.

use super::parts::{
    Context, Declared, ImageLook, LINT_MAX_DIMS, Part, Run, TIMESTAMP_TOLERANCE_SECS,
    is_index_column,
};
use crate::episode::{Episode, EpisodeMeta, MAX_OBJECTS, POSE_VALUES, Step};
use crate::export::check::Check;
use crate::export::findings::{At, Semantics, check_semantics};
use crate::export::lint::cameras::{FrameLook, LOOK_EVERY, could_be_blank, hash};
use crate::media::image::{decode_png, png_size};
use crate::media::png_rows::{PngRows, inflate_rows, unfilter};
use crate::media::tiff::f32_tiff_size;
use arrow_array::{
    Array, BinaryArray, BinaryViewArray, FixedSizeListArray, Float32Array, Float64Array,
    Int64Array, LargeBinaryArray, RecordBatch, StructArray,
};
use arrow_schema::DataType;
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ParquetRecordBatchReaderBuilder, RowSelection, RowSelector,
};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

impl Context<'_> {
    pub(super) fn check_row_group(
        &self,
        path: &Path,
        metadata: &ArrowReaderMetadata,
        group: usize,
    ) -> Part {
        let file = self.findings.relative(path);
        let mut part = Part::default();
        if group == 0 && self.info_known {
            self.check_columns(metadata.schema(), &file);
        }
        // Quick: every row of every column but the images (indices, timestamps, numbers: what
        // the full pass reads of them, so the two never disagree on them), and the images of
        // the row group's first row.
        let schema = metadata.schema();
        let is_image =
            |name: &str| (self.features.iter()).any(|f| f.name == name && f.dtype == "image");
        let roots = |keep: &dyn Fn(&str) -> bool| {
            let indices = (schema.fields().iter().enumerate())
                .filter(|(_, field)| keep(field.name()))
                .map(|(i, _)| i);
            ProjectionMask::roots(metadata.metadata().file_metadata().schema_descr(), indices)
        };
        let quick = self.quick;
        let main = quick.then(|| roots(&|name| !is_image(name)));
        let has_images = schema.fields().iter().any(|f| is_image(f.name()));
        let first_images =
            (quick && has_images).then(|| roots(&|name| is_image(name) || is_index_column(name)));
        let Some(reader) = self.row_group_reader(path, metadata, group, main, false) else {
            return part;
        };
        // Our datasets' episodes, as far as the semantic checks need them (full pass only).
        let mut semantic_rows: Vec<(i64, Step)> = Vec::new();
        for batch in reader {
            let batch = match batch {
                Ok(batch) => batch,
                Err(problem) => {
                    self.findings.error(
                        At::file(file.clone()),
                        Check::Readable,
                        format!("row group {group} cannot be decoded: {problem}"),
                    );
                    return part;
                }
            };
            let batch = crate::export::lerobot::table::fixed_size_lists(batch);
            self.check_batch(&batch, &file, &mut part, &mut semantic_rows);
        }
        if let Some(projection) = first_images {
            let reader = self.row_group_reader(path, metadata, group, Some(projection), true);
            for batch in reader.into_iter().flatten() {
                match batch {
                    Ok(batch) => {
                        self.check_first_images(&batch, &file);
                    }
                    Err(problem) => self.findings.error(
                        At::file(file.clone()),
                        Check::Readable,
                        format!("row group {group} cannot be decoded: {problem}"),
                    ),
                }
            }
        }
        if let Some(semantics) = self.semantics.filter(|_| !self.quick) {
            self.check_episodes_semantics(&file, semantics, semantic_rows);
        }
        part
    }

    /// A reader of row group `group` of `path`: the `projection`'s columns (all: None), its
    /// first row only when `first_row`; None (a finding made) when it cannot be read.
    fn row_group_reader(
        &self,
        path: &Path,
        metadata: &ArrowReaderMetadata,
        group: usize,
        projection: Option<ProjectionMask>,
        first_row: bool,
    ) -> Option<parquet::arrow::arrow_reader::ParquetRecordBatchReader> {
        let reader = crate::files::open_regular(path)
            .map_err(|e| e.to_string())
            .map(|f| ParquetRecordBatchReaderBuilder::new_with_metadata(f, metadata.clone()))
            .and_then(|builder| {
                let rows = builder.metadata().row_group(group).num_rows() as usize;
                let mut builder = builder.with_row_groups(vec![group]).with_batch_size(256);
                if let Some(projection) = projection {
                    builder = builder.with_projection(projection);
                }
                if first_row && rows > 1 {
                    builder = builder.with_row_selection(RowSelection::from(vec![
                        RowSelector::select(1),
                        RowSelector::skip(rows - 1),
                    ]));
                }
                builder.build().map_err(|e| e.to_string())
            });
        match reader {
            Ok(reader) => Some(reader),
            Err(problem) => {
                self.findings.error(
                    At::file(self.findings.relative(path)),
                    Check::Readable,
                    format!("row group {group}: {problem}"),
                );
                None
            }
        }
    }

    /// Quick: the images of a row group's first row (`batch`: its image and index columns).
    fn check_first_images(&self, batch: &RecordBatch, file: &str) -> Vec<ImageLook> {
        let ints = |name: &str| -> Vec<i64> {
            (batch.column_by_name(name))
                .and_then(|c| c.as_any().downcast_ref::<Int64Array>())
                .map(|a| a.values().to_vec())
                .unwrap_or_else(|| vec![0; batch.num_rows()])
        };
        let (episode, frame) = (ints("episode_index"), ints("frame_index"));
        let mut looks = Vec::new();
        for feature in self.features.iter().filter(|f| f.dtype == "image") {
            if let Some(column) = batch.column_by_name(&feature.name) {
                looks.extend(self.check_images(feature, column.as_ref(), &episode, &frame, file));
            }
        }
        looks
    }

    /// The columns are exactly the declared features (video features live in MP4 files).
    fn check_columns(&self, schema: &arrow_schema::Schema, file: &str) {
        for feature in self.features.iter().filter(|f| f.dtype != "video") {
            let Some(field) = schema.field_with_name(&feature.name).ok() else {
                self.findings.error(
                    At::file(file),
                    Check::Columns,
                    format!("the declared feature {} has no column", feature.name),
                );
                continue;
            };
            if let Some(problem) = type_problem(feature, field.data_type()) {
                self.findings.error(
                    At::file(file),
                    Check::Types,
                    format!("{}: {problem}", feature.name),
                );
            }
        }
        for field in schema.fields() {
            let declared = self
                .features
                .iter()
                .any(|f| &f.name == field.name() && f.dtype != "video");
            if !declared {
                self.findings.error(
                    At::file(file),
                    Check::Columns,
                    format!(
                        "column {} is not a declared feature of meta/info.json",
                        field.name()
                    ),
                );
            }
        }
    }

    fn check_batch(
        &self,
        batch: &RecordBatch,
        file: &str,
        part: &mut Part,
        semantic_rows: &mut Vec<(i64, Step)>,
    ) {
        let findings = self.findings;
        let ints = |name: &str| -> Option<Vec<i64>> {
            let column = batch.column_by_name(name)?;
            if let Some(a) = column.as_any().downcast_ref::<Int64Array>() {
                return Some(a.values().to_vec());
            }
            let list = column.as_any().downcast_ref::<FixedSizeListArray>()?;
            let values = list.values().as_any().downcast_ref::<Int64Array>()?;
            (list.value_length() == 1).then(|| values.values().to_vec())
        };
        let (Some(index), Some(episode), Some(frame)) =
            (ints("index"), ints("episode_index"), ints("frame_index"))
        else {
            findings.error(
                At::file(file),
                Check::Columns,
                "lacks an int64 index, episode_index or frame_index column",
            );
            return;
        };
        let task = ints("task_index");
        let timestamp = batch.column_by_name("timestamp").and_then(|c| {
            c.as_any()
                .downcast_ref::<Float32Array>()
                .map(|a| a.values().iter().map(|&v| f64::from(v)).collect::<Vec<_>>())
                .or_else(|| {
                    c.as_any()
                        .downcast_ref::<Float64Array>()
                        .map(|a| a.values().to_vec())
                })
        });
        let columns = IndexColumns {
            index: &index,
            episode: &episode,
            frame: &frame,
            task: task.as_deref(),
            timestamp: timestamp.as_deref(),
        };
        self.check_row_order(&columns, file, part);
        if self.lint {
            for row in 0..index.len() {
                let series = part.series.entry(episode[row]).or_default();
                series.episode = episode[row].max(0) as u64;
                if series.task.is_none() {
                    series.task = task.as_ref().map(|t| t[row]);
                }
                if let Some(timestamp) = &timestamp {
                    series.timestamps_secs.push(timestamp[row]);
                }
            }
        }
        part.rows += batch.num_rows() as u64;
        let judged = self.semantics.is_some() && !self.quick;
        let mut steps: Vec<Step> = if judged {
            (0..batch.num_rows()).map(|_| Step::empty()).collect()
        } else {
            Vec::new()
        };
        for feature in self.features.iter().filter(|f| !is_index_column(&f.name)) {
            let Some(column) = batch.column_by_name(&feature.name) else {
                continue;
            };
            match feature.dtype.as_str() {
                "float32" | "float64" => {
                    self.float_feature(feature, column.as_ref(), &columns, file, part, &mut steps);
                }
                "image" => {
                    let looks = self.check_images(feature, column.as_ref(), &episode, &frame, file);
                    part.looks.extend(looks);
                }
                _ => {}
            }
        }
        semantic_rows.extend(episode.iter().copied().zip(steps));
    }

    /// Within the row group: indices and frame indices contiguous per episode (gathered into
    /// runs for the cross-group checks), timestamps at frame_index / fps, task indices in the
    /// tasks table.
    fn check_row_order(&self, columns: &IndexColumns<'_>, file: &str, part: &mut Part) {
        let findings = self.findings;
        for row in 0..columns.index.len() {
            let at = || {
                At::file(file)
                    .episode(columns.episode[row].max(0) as u64)
                    .frame(columns.frame[row].max(0) as u64)
            };
            match part.runs.last_mut() {
                Some(run) if run.episode == columns.episode[row] => {
                    if columns.index[row] != run.last_index + 1 {
                        findings.error(
                            at(),
                            Check::Index,
                            format!("index {} follows {}", columns.index[row], run.last_index),
                        );
                    }
                    if columns.frame[row] != run.last_frame + 1 {
                        findings.error(
                            at(),
                            Check::FrameIndex,
                            format!(
                                "frame_index {} follows {}",
                                columns.frame[row], run.last_frame
                            ),
                        );
                    }
                    run.last_index = columns.index[row];
                    run.last_frame = columns.frame[row];
                    run.rows += 1;
                }
                _ => part.runs.push(Run {
                    episode: columns.episode[row],
                    first_index: columns.index[row],
                    last_index: columns.index[row],
                    first_frame: columns.frame[row],
                    last_frame: columns.frame[row],
                    rows: 1,
                }),
            }
            if let (Some(timestamps), Some(fps)) = (columns.timestamp, self.fps) {
                let expected = columns.frame[row] as f64 / fps;
                if (timestamps[row] - expected).abs() > TIMESTAMP_TOLERANCE_SECS {
                    findings.error(
                        at(),
                        Check::Timestamps,
                        format!(
                            "timestamp {} s where frame_index / fps = {expected:.6} s",
                            timestamps[row]
                        ),
                    );
                }
            }
            if let Some(task) = columns.task
                && (task[row] < 0 || task[row] as usize >= self.tasks)
            {
                findings.error(
                    at(),
                    Check::TaskIndex,
                    format!(
                        "task_index {} is not in the tasks table ({} tasks)",
                        task[row], self.tasks
                    ),
                );
            }
        }
    }

    /// A float feature's values: finite (else a finding), gathered into the statistics'
    /// moments, and, for our 7-D state and action and the object poses, into the steps the
    /// semantic checks judge.
    fn float_feature(
        &self,
        feature: &Declared,
        column: &dyn arrow_array::Array,
        columns: &IndexColumns<'_>,
        file: &str,
        part: &mut Part,
        steps: &mut [Step],
    ) {
        let findings = self.findings;
        let Some(values) = float_values(column, feature.elements()) else {
            return;
        };
        let n = feature.elements();
        if self.lint && n <= LINT_MAX_DIMS {
            // Row by row into each episode's series, looked up once per run of its rows.
            let mut row = 0;
            while row < columns.episode.len() {
                let episode = columns.episode[row];
                let end = (row..columns.episode.len())
                    .find(|&r| columns.episode[r] != episode)
                    .unwrap_or(columns.episode.len());
                let series = part.series.entry(episode).or_default();
                if !series.features.contains_key(&feature.name) {
                    series
                        .features
                        .insert(feature.name.clone(), Default::default());
                }
                if let Some(into) = series.features.get_mut(&feature.name) {
                    into.dims = n;
                    let chunk = values.get(row * n..end * n).unwrap_or_default();
                    into.values.extend(chunk.iter().map(|v| *v as f32));
                }
                row = end;
            }
        }
        let moments = part
            .moments
            .entry(feature.name.clone())
            .or_insert_with(|| vec![(f64::INFINITY, f64::NEG_INFINITY, 0.0, 0); n]);
        for (row, chunk) in values.chunks_exact(n).enumerate() {
            if let Some(bad) = chunk.iter().find(|v| !v.is_finite()) {
                let at = At::file(file)
                    .episode(columns.episode[row].max(0) as u64)
                    .frame(columns.frame[row].max(0) as u64);
                findings.error(at, Check::Finite, format!("{} holds {bad}", feature.name));
                continue;
            }
            for (m, &v) in moments.iter_mut().zip(chunk) {
                *m = (m.0.min(v), m.1.max(v), m.2 + v, m.3 + 1);
            }
            let Some(step) = steps.get_mut(row) else {
                continue;
            };
            let target: Option<&mut [f32]> = match feature.name.as_str() {
                "observation.state" if n == 7 => Some(&mut step.state),
                "action" if n == 7 => Some(&mut step.action),
                "observation.environment_state" if n == MAX_OBJECTS * POSE_VALUES => {
                    Some(&mut step.environment_state)
                }
                _ => None,
            };
            if let Some(target) = target {
                for (t, v) in target.iter_mut().zip(chunk) {
                    *t = *v as f32;
                }
            }
        }
    }

    /// A batch's PNG buffers for `feature`: its pictures looked at every [`LOOK_EVERY`] frames
    /// only where a camera of the same shape could have been swapped with it.
    fn png_scratch(&self, feature: &Declared) -> PngScratch {
        let paired = (self.features.iter()).any(|f| {
            f.name != feature.name
                && f.dtype == "image"
                && f.shape == feature.shape
                && !crate::export::lint::cameras::is_mask(&f.name)
        });
        PngScratch {
            every: paired.then_some(LOOK_EVERY),
            ..PngScratch::default()
        }
    }

    fn check_images(
        &self,
        feature: &Declared,
        column: &dyn Array,
        episode: &[i64],
        frame: &[i64],
        file: &str,
    ) -> Vec<ImageLook> {
        let findings = self.findings;
        let mut looks = Vec::new();
        let Some(images) = column.as_any().downcast_ref::<StructArray>() else {
            return looks;
        };
        let image_bytes = image_bytes(images);
        let (height, width) = (
            feature.shape.first().copied().unwrap_or(0),
            feature.shape.get(1).copied().unwrap_or(0),
        );
        let channels = feature.shape.get(2).copied().unwrap_or(1);
        // The lint looks at cameras in the full pass (a segmentation mask is not one).
        let looked =
            self.lint && !self.quick && !crate::export::lint::cameras::is_mask(&feature.name);
        let mut scratch = self.png_scratch(feature);
        for row in 0..images.len() {
            let at = || {
                At::file(file)
                    .episode(episode[row].max(0) as u64)
                    .frame(frame[row].max(0) as u64)
            };
            let Some(encoded) = image_bytes(row).filter(|e| !e.is_empty()) else {
                findings.error(
                    at(),
                    Check::Image,
                    format!("{} has no image bytes", feature.name),
                );
                continue;
            };
            let decoded = decode_image(
                encoded,
                (width, height, channels),
                (episode[row], frame[row]),
                looked,
                &mut scratch,
            );
            let decoded = decoded.map(|(size, look)| {
                if let (Some(size), Some(look)) = (size, look) {
                    looks.push((episode[row], feature.name.clone(), size, look));
                }
                size
            });
            let (w, h, c) = match decoded {
                Ok(Some(size)) => size,
                Ok(None) => continue,
                Err(problem) => {
                    findings.error(
                        at(),
                        Check::Image,
                        format!("{} does not decode: {problem}", feature.name),
                    );
                    continue;
                }
            };
            if (w, h) != (width, height) {
                findings.error(
                    at(),
                    Check::Image,
                    format!("{} is {w}x{h}, declared {width}x{height}", feature.name),
                );
            }
            if c != channels {
                let what = if c == 4 {
                    " (RGBA: lerobot and OpenVLA expect RGB)"
                } else {
                    ""
                };
                findings.error(
                    at(),
                    Check::Image,
                    format!(
                        "{} has {c} channels, declared {channels}{what}",
                        feature.name
                    ),
                );
            }
        }
        looks
    }

    /// Groups rows into episodes and runs the shared semantic checks.
    /// Groups one row group's rows into episodes and runs our datasets' semantic checks.
    fn check_episodes_semantics(&self, file: &str, semantics: &Semantics, rows: Vec<(i64, Step)>) {
        let mut rows = rows.into_iter().peekable();
        while let Some((episode, first)) = rows.next() {
            let mut steps = vec![first];
            while let Some((_, step)) = rows.next_if(|(e, _)| *e == episode) {
                steps.push(step);
            }
            let entry = self.entries.get(episode.max(0) as usize);
            let provenance = |key: &str| {
                entry
                    .and_then(|e| e.provenance.get(key))
                    .cloned()
                    .unwrap_or(Value::Null)
            };
            let meta = EpisodeMeta {
                index: episode.max(0) as u64,
                task_code: provenance("surgvla/task_id")
                    .as_str()
                    .unwrap_or_default()
                    .into(),
                task_name: String::new(),
                level: provenance("surgvla/level").as_u64().unwrap_or(0) as u8,
                instruction: String::new(),
                seed: provenance("surgvla/seed").as_i64().unwrap_or(0) as u64,
                attempts: provenance("surgvla/attempts").as_u64().unwrap_or(0) as u32,
                success: provenance("surgvla/success").as_bool().unwrap_or(false),
                task_changes: Vec::new(),
                fields: serde_json::Map::new(),
            };
            // A part of an episode cannot be judged against its step limit.
            let whole = entry.and_then(|e| e.length) == Some(steps.len() as i64);
            let semantics = Semantics {
                step_limits: if whole {
                    semantics.step_limits.clone()
                } else {
                    BTreeMap::new()
                },
                ..semantics.clone()
            };
            let episode = Episode {
                meta,
                steps,
                encoded: Vec::new(),
                image_stats: Vec::new(),
                stored_rows: None,
            };
            check_semantics(&episode, &semantics, &At::file(file), self.findings);
        }
    }
}

/// The values of a float feature's column, row-major, when it has `n` per row.
fn float_values(column: &dyn Array, n: usize) -> Option<Vec<f64>> {
    let any = column.as_any();
    let values = if let Some(list) = any.downcast_ref::<FixedSizeListArray>() {
        if list.value_length() as usize != n {
            return None;
        }
        let inner = list.values();
        let offset = list.offset() * n;
        let len = list.len() * n;
        if let Some(a) = inner.as_any().downcast_ref::<Float32Array>() {
            a.values()[offset..offset + len]
                .iter()
                .map(|&v| f64::from(v))
                .collect()
        } else {
            inner.as_any().downcast_ref::<Float64Array>()?.values()[offset..offset + len].to_vec()
        }
    } else if n == 1 {
        if let Some(a) = any.downcast_ref::<Float32Array>() {
            a.values().iter().map(|&v| f64::from(v)).collect()
        } else {
            any.downcast_ref::<Float64Array>()?.values().to_vec()
        }
    } else {
        return None;
    };
    Some(values)
}

/// What is wrong with a column's type for its declared feature, if anything.
fn type_problem(feature: &Declared, data_type: &DataType) -> Option<String> {
    let scalar = |wanted: &DataType| -> Option<String> {
        let n = feature.elements();
        match data_type {
            DataType::FixedSizeList(item, len)
                if item.data_type() == wanted && *len as usize == n =>
            {
                None
            }
            t if t == wanted && n == 1 => None,
            // Variable-length lists (pandas, lerobot's edit tool): each row's length is
            // checked where the values are read.
            DataType::List(item) | DataType::LargeList(item)
                if item.data_type() == wanted && n > 1 =>
            {
                None
            }
            DataType::FixedSizeList(item, len) => Some(format!(
                "stored as {len} x {}, declared {} x {n}",
                item.data_type(),
                feature.dtype
            )),
            t => Some(format!(
                "stored as {t}, declared {} with shape {:?}",
                feature.dtype, feature.shape
            )),
        }
    };
    match feature.dtype.as_str() {
        "float32" => scalar(&DataType::Float32),
        "float64" => scalar(&DataType::Float64),
        "int64" => scalar(&DataType::Int64),
        "bool" => scalar(&DataType::Boolean),
        "string" => match data_type {
            DataType::Utf8 | DataType::LargeUtf8 => None,
            t => Some(format!("stored as {t}, declared string")),
        },
        "image" => match data_type {
            DataType::Struct(fields) if fields.iter().any(|f| f.name() == "bytes") => None,
            t => Some(format!(
                "stored as {t}, declared image (a struct with bytes and path)"
            )),
        },
        _ => None,
    }
}

/// A row group's index columns, as the row checks read them.
struct IndexColumns<'a> {
    index: &'a [i64],
    episode: &'a [i64],
    frame: &'a [i64],
    task: Option<&'a [i64]>,
    timestamp: Option<&'a [f64]>,
}

/// A decoded image's (width, height, channels) and the lint's look at it.
type Looked = ((usize, usize, usize), FrameLook);

/// Row `row`'s encoded image of an image struct column (None: null or no `bytes` field), its
/// `bytes` binary, large binary or a view.
fn image_bytes<'a>(images: &'a StructArray) -> impl Fn(usize) -> Option<&'a [u8]> + 'a {
    let bytes = images.column_by_name("bytes");
    let binary = bytes.and_then(|b| b.as_any().downcast_ref::<BinaryArray>());
    let large = bytes.and_then(|b| b.as_any().downcast_ref::<LargeBinaryArray>());
    let view = bytes.and_then(|b| b.as_any().downcast_ref::<BinaryViewArray>());
    move |row| {
        if bytes.is_none_or(|b| b.is_null(row)) {
            return None;
        }
        (binary.map(|b| b.value(row)))
            .or_else(|| large.map(|b| b.value(row)))
            .or_else(|| view.map(|b| b.value(row)))
    }
}

/// Buffers a batch's PNG frames inflate into, the last frame's (episode, hash), and how often
/// pictures are looked at whatever they show.
#[derive(Default)]
struct PngScratch {
    rows: Vec<u8>,
    pixels: Vec<u8>,
    last: Option<(i64, u64)>,
    every: Option<u64>,
}

/// An encoded image's decoded size and, with the lint (full pass), its look. A size other
/// than the declared one is known from the PNG header: nothing is decoded. PNGs of the common
/// layout are checked and inflated without being unfiltered ([`inflate_rows`]); their pixels
/// are wanted only for the lint's look, and only at some frames ([`LOOK_EVERY`]).
#[allow(clippy::type_complexity)]
fn decode_image(
    encoded: &[u8],
    (width, height, channels): (usize, usize, usize),
    (episode, frame): (i64, i64),
    looked: bool,
    scratch: &mut PngScratch,
) -> Result<(Option<(usize, usize, usize)>, Option<FrameLook>), String> {
    if let Some(header) = inflate_rows(encoded, Some((width, height)), &mut scratch.rows) {
        let size = (header.width, header.height, header.channels);
        let look = looked.then(|| png_look(&header, (episode, frame), scratch));
        return Ok((Some(size), look));
    }
    if let Some((w, h)) = png_size(encoded).filter(|size| *size != (width, height)) {
        return Ok((Some((w, h, channels)), None));
    }
    if looked && encoded.starts_with(b"\x89PNG") {
        return decoded_look(encoded, frame).map(|looked| match looked {
            Some((size, look)) => (Some(size), Some(look)),
            None => (None, None),
        });
    }
    decoded_size(encoded).map(|size| (size, None))
}

/// The lint's look at an inflated PNG frame: its filtered rows hashed, its pixels looked at
/// where [`LOOK_EVERY`] says so.
fn png_look(header: &PngRows, (episode, frame): (i64, i64), scratch: &mut PngScratch) -> FrameLook {
    let rows_hash = hash(&scratch.rows);
    let repeated = scratch.last == Some((episode, rows_hash));
    scratch.last = Some((episode, rows_hash));
    let frame = frame.max(0) as u64;
    let due = scratch
        .every
        .is_some_and(|every| frame.is_multiple_of(every));
    let (stride, pixel_bytes) = (header.stride(), header.pixel_bytes());
    if !(due || repeated || could_be_blank(&scratch.rows, stride, pixel_bytes)) {
        return FrameLook::unseen(frame, rows_hash);
    }
    unfilter(header, &scratch.rows, &mut scratch.pixels);
    let (width, height) = (header.width, header.height);
    if header.bit_depth == 16 {
        // The high bytes of each sample, as the png crate's path looks at them.
        let high: Vec<u8> = scratch.pixels.iter().step_by(2).copied().collect();
        let channels = header.channels;
        return FrameLook::of_hashed(frame, (width, height, channels), &high, rows_hash);
    }
    let shape = (width, height, header.channels);
    FrameLook::of_hashed(frame, shape, &scratch.pixels, rows_hash)
}

/// A PNG's decoded size, as [`decoded_size`], with the lint's look at its pixels (8-bit: its
/// channels; 16-bit: the high bytes).
fn decoded_look(encoded: &[u8], frame: i64) -> Result<Option<Looked>, String> {
    let frame = frame.max(0) as u64;
    match decode_png(encoded) {
        Ok((w, h, c, pixels)) => {
            let (w, h) = (w as usize, h as usize);
            Ok(Some(((w, h, c), FrameLook::of(frame, w, h, c, &pixels))))
        }
        Err(e) => crate::media::image::decode_png16(encoded)
            .map(|(w, h, values)| {
                let (w, h) = (w as usize, h as usize);
                let high: Vec<u8> = values.iter().map(|v| (v >> 8) as u8).collect();
                Some(((w, h, 1), FrameLook::of(frame, w, h, 1, &high)))
            })
            .map_err(|_| e),
    }
}

/// An encoded image's (width, height, channels) once decoded: PNG (8 or 16 bit) or a float32
/// TIFF; None for a JPEG, which is not decoded here.
fn decoded_size(encoded: &[u8]) -> Result<Option<(usize, usize, usize)>, String> {
    if encoded.starts_with(&[0xff, 0xd8]) {
        return Ok(None);
    }
    if encoded.starts_with(b"II*\0") || encoded.starts_with(b"MM\0*") {
        return f32_tiff_size(encoded)
            .map(|(w, h)| Some((w as usize, h as usize, 1)))
            .ok_or_else(|| "a TIFF that is not a float32 depth image".to_string());
    }
    decode_png(encoded)
        .map(|(w, h, c, _)| Some((w as usize, h as usize, c)))
        .or_else(|e| {
            crate::media::image::decode_png16(encoded)
                .map(|(w, h, _)| Some((w as usize, h as usize, 1)))
                .map_err(|_| e)
        })
}
