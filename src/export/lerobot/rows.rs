//! A LeRobot dataset's data files read row group by row group ([`DataRows`]): frame rows
//! ([`Row`]) with their images still encoded, and for what only lists or passes over episodes,
//! less. surgvla (and lerobot through pyarrow) writes each episode as whole row groups whose
//! `episode_index` statistics name it; such a group is passed over without reading a byte of
//! it ([`DataRows::skip_group`]), or read without its image columns
//! ([`DataRows::read_group`], `images: false`), which are nearly all of a file's bytes. A group
//! whose statistics name no single episode is read whole, 64 rows at a time, and the rows say
//! where each episode ends.
//!
//! Here too: a parquet footer checked before anything it claims is allocated
//! ([`footer_problem`]), and the typed column access the readers share.

use crate::episode::{Dtype, FeatureKind, FeatureSpec, FeatureValue, Step};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use arrow_array::{
    Array, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array,
    LargeStringArray, RecordBatch, StringArray, StructArray,
};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ParquetRecordBatchReader, ParquetRecordBatchReaderBuilder,
};
use std::fs::File;
use std::path::{Path, PathBuf};

/// Rows read at a time from a group read whole: a few rows' images, not an episode's.
const BATCH_ROWS: usize = 64;
/// Rows read at a time from a group read without its images (a few hundred bytes a row).
const LIGHT_BATCH_ROWS: usize = 4096;

/// One frame's row as stored.
pub(super) struct Row {
    pub episode: i64,
    pub task: i64,
    pub step: Step,
    /// The row's `timestamp` (seconds), if the data has the column.
    pub timestamp_secs: Option<f64>,
    /// The encoded bytes of the RGB, mask and depth images, in the order of
    /// [`super::read::step_images`]: decoded when the episode is put together, never for a
    /// skipped one; empty when the row was read without its images.
    pub images: Vec<Vec<u8>>,
    /// The data file the row is in.
    pub file: std::sync::Arc<Path>,
}

/// What comes next in the data files.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Next {
    /// A row group whose statistics say it holds episode `episode` only.
    Episode(i64),
    /// Rows whose episodes only reading them tells (a group read whole, or one whose
    /// statistics name no single episode): [`DataRows::read_batch`].
    Rows,
}

/// An open data file.
struct OpenFile {
    path: PathBuf,
    file: File,
    metadata: ArrowReaderMetadata,
    /// When its row groups can be copied by the writer (see [`DataRows::leave_stored`]): the
    /// file opened for the writer to read them from.
    copyable: Option<std::sync::Arc<File>>,
    /// The row group read next.
    group: usize,
    /// A group being read whole, 64 rows at a time.
    reader: Option<ParquetRecordBatchReader>,
    /// The light columns a copy reads are small reads between large columns it does not, so
    /// the kernel's own read-ahead never starts: asked for by the reader.
    read_ahead: crate::files::ReadAhead,
    /// The episodes that will be read ([`DataRows::taking_only`]), when others are skipped.
    taking: Option<Taking>,
}

/// The episodes a reader will read, by index.
type Taking = std::sync::Arc<std::collections::BTreeSet<u64>>;

/// The data files, in order, read as [`Next`] says.
pub(super) struct DataRows {
    files: std::vec::IntoIter<PathBuf>,
    open: Option<OpenFile>,
    /// The schema the writer would give the frame rows, when row groups are to be offered
    /// for copying ([`DataRows::leave_stored`]).
    copy: Option<arrow_schema::SchemaRef>,
    /// The episodes that will be read ([`DataRows::taking_only`]).
    taking: Option<Taking>,
}

impl DataRows {
    pub(super) fn new(files: Vec<PathBuf>) -> Self {
        DataRows {
            files: files.into_iter(),
            open: None,
            copy: None,
            taking: None,
        }
    }

    /// Only `episodes` will be read from now on, the others' row groups skipped: the reader
    /// asks for the groups of those episodes alone to be read ahead (the file open now
    /// included), so that the others' bytes stay on the disk.
    pub(super) fn taking_only(&mut self, episodes: Taking) {
        if let Some(open) = &mut self.open {
            open.taking = Some(std::sync::Arc::clone(&episodes));
        }
        self.taking = Some(episodes);
    }

    /// From the next file opened on, offers a row group for copying ([`DataRows::stored_group`])
    /// when its file stores the columns as the writer of `schema` would.
    pub(super) fn leave_stored(&mut self, schema: arrow_schema::SchemaRef) {
        self.copy = Some(schema);
    }

    /// The row group read next, for the writer to copy, if its file allows.
    pub(super) fn stored_group(&self) -> Option<super::copy::StoredGroup> {
        let open = self.open.as_ref().filter(|o| o.reader.is_none())?;
        let handle = open.copyable.clone()?;
        (open.group < open.metadata.metadata().num_row_groups()).then(|| super::copy::StoredGroup {
            file: std::sync::Arc::from(open.path.as_path()),
            handle,
            metadata: open.metadata.metadata().clone(),
            row_group: open.group,
        })
    }

    /// What comes next (None: the files are done), opening the next file when one is done.
    pub(super) fn next(&mut self) -> Result<Option<Next>, ExportError> {
        loop {
            if let Some(open) = &self.open {
                if open.reader.is_some() {
                    return Ok(Some(Next::Rows));
                }
                let groups = open.metadata.metadata().row_groups();
                if let Some(group) = groups.get(open.group) {
                    return Ok(Some(
                        single_episode(group).map_or(Next::Rows, Next::Episode),
                    ));
                }
            }
            let Some(path) = self.files.next() else {
                self.open = None;
                return Ok(None);
            };
            let (file, metadata) = open_parquet_metadata(&path, self.copy.is_some())?;
            let copyable = match &self.copy {
                Some(schema) if super::copy::matches_writer(metadata.parquet_schema(), schema) => {
                    let handle = crate::export::bounded::open_regular(&path)?;
                    Some(std::sync::Arc::new(handle))
                }
                _ => None,
            };
            self.open = Some(OpenFile {
                path,
                file,
                metadata,
                copyable,
                group: 0,
                reader: None,
                read_ahead: crate::files::ReadAhead::default(),
                taking: self.taking.clone(),
            });
        }
    }

    /// The row groups from the next one on that hold episode `episode` alone, each with its
    /// rows and its one task, as their statistics say (none read): None when one of them has
    /// rows of several tasks, when a group of several episodes follows them, or when they reach
    /// the end of the file (the episode may go on in the next).
    pub(super) fn counted_groups(&self, episode: i64) -> Option<Vec<(u64, i64)>> {
        let open = self.open.as_ref().filter(|o| o.reader.is_none())?;
        let groups = open.metadata.metadata().row_groups().get(open.group..)?;
        let mut counted = Vec::new();
        for group in groups {
            match single_episode(group) {
                Some(alone) if alone == episode => {}
                // The next episode's alone: this one ended with the group before.
                Some(_) if !counted.is_empty() => return Some(counted),
                // A group mixing episodes may hold more of this one's rows.
                _ => return None,
            }
            let task = single_value(group, "task_index")?;
            counted.push((u64::try_from(group.num_rows()).ok()?, task));
        }
        None
    }

    /// Passes over the next row group unread.
    pub(super) fn skip_group(&mut self) {
        if let Some(open) = &mut self.open {
            open.group += 1;
        }
    }

    /// Every row of the next row group, with its images or without.
    pub(super) fn read_group(
        &mut self,
        info: &DatasetInfo,
        images: bool,
    ) -> Result<Vec<Row>, ExportError> {
        let Some(open) = &mut self.open else {
            return Ok(Vec::new());
        };
        let batch_rows = if images { BATCH_ROWS } else { LIGHT_BATCH_ROWS };
        let (mut reader, known) = open.reader(info, images, batch_rows)?;
        let mut rows = Vec::new();
        for batch in &mut reader {
            let batch = super::table::fixed_size_lists(batch.map_err(ExportError::Arrow)?);
            rows.extend(rows_of(&batch, &open.path, info, images, known)?);
        }
        Ok(rows)
    }

    /// The next 64 rows of the group being read whole (started when none is); None when the
    /// files are done.
    pub(super) fn read_batch(
        &mut self,
        info: &DatasetInfo,
    ) -> Result<Option<Vec<Row>>, ExportError> {
        loop {
            if self.next()?.is_none() {
                return Ok(None);
            }
            let Some(open) = &mut self.open else {
                return Ok(None);
            };
            if open.reader.is_none() {
                let (reader, _) = open.reader(info, true, BATCH_ROWS)?;
                open.reader = Some(reader);
            }
            let Some(reader) = &mut open.reader else {
                continue;
            };
            match reader.next() {
                Some(batch) => {
                    let batch = super::table::fixed_size_lists(batch.map_err(ExportError::Arrow)?);
                    return rows_of(&batch, &open.path, info, true, Known::default()).map(Some);
                }
                None => open.reader = None,
            }
        }
    }
}

impl OpenFile {
    /// A reader of the next row group (which it passes), with its image columns or without;
    /// without them, the `episode_index` and `task_index` columns are left out when the group's
    /// statistics say their one value, which is returned. Each column read costs a
    /// decompressor, and the writer numbers the episode anew anyway.
    fn reader(
        &mut self,
        info: &DatasetInfo,
        images: bool,
        batch_rows: usize,
    ) -> Result<(ParquetRecordBatchReader, Known), ExportError> {
        let group = self.group;
        self.group += 1;
        self.read_ahead(group);
        let file = self.file.try_clone().map_err(ExportError::io(&self.path))?;
        let mut builder =
            ParquetRecordBatchReaderBuilder::new_with_metadata(file, self.metadata.clone())
                .with_row_groups(vec![group])
                .with_batch_size(batch_rows);
        let mut known = Known::default();
        if !images {
            if let Some(group) = self.metadata.metadata().row_groups().get(group) {
                known = Known::of(group);
            }
            let schema = self.metadata.parquet_schema();
            builder = builder.with_projection(light_projection(schema, info, known));
        }
        let reader = builder.build().map_err(ExportError::parquet(&self.path))?;
        Ok((reader, known))
    }
}

impl OpenFile {
    /// Has the kernel read the file ahead from row group `group`, which is about to be read,
    /// through the groups after it (adjacent ones in one piece): those of the episodes taken
    /// alone, when [`DataRows::taking_only`] named them (a group its statistics do not give
    /// one episode of counts as taken).
    fn read_ahead(&mut self, group: usize) {
        let groups = self.metadata.metadata().row_groups();
        let Some((this, after)) = groups.get(group..).and_then(|g| g.split_first()) else {
            return;
        };
        let taking = self.taking.as_deref();
        let taken = |g: &&parquet::file::metadata::RowGroupMetaData| {
            let taken =
                |e: i64| taking.is_none_or(|t| u64::try_from(e).is_ok_and(|e| t.contains(&e)));
            single_episode(g).is_none_or(taken)
        };
        let spans = std::iter::once(this).chain(after.iter().filter(taken));
        self.read_ahead
            .reading_spans(&self.file, spans.map(group_span));
    }
}

/// Where a row group's column chunks lie in its file, in bytes.
fn group_span(group: &parquet::file::metadata::RowGroupMetaData) -> std::ops::Range<u64> {
    super::copy::chunks_span(group.columns())
}

/// The one episode and the one task of a row group's rows, where its statistics say them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Known {
    episode: Option<i64>,
    task: Option<i64>,
}

impl Known {
    fn of(group: &parquet::file::metadata::RowGroupMetaData) -> Known {
        let [_, task_column, _] = ROW_COLUMNS;
        Known {
            episode: single_episode(group),
            task: single_value(group, task_column),
        }
    }
}

/// An integer column of a batch, or the one value a row group's statistics give it.
enum Ints<'a> {
    One(i64),
    Read(&'a Int64Array),
}

impl Ints<'_> {
    /// Column `name` of `batch`, unless `known` gives its value.
    fn of<'a>(
        batch: &'a RecordBatch,
        name: &str,
        known: Option<i64>,
        path: &Path,
    ) -> Result<Ints<'a>, ExportError> {
        match known {
            Some(value) => Ok(Ints::One(value)),
            None => column::<Int64Array>(batch, name, path).map(Ints::Read),
        }
    }

    fn value(&self, row: usize) -> i64 {
        match self {
            Ints::One(value) => *value,
            Ints::Read(column) => column.value(row),
        }
    }
}

/// The default columns a [`Row`] holds, read by `rows_of` (episode, task, timestamp): the others
/// (`index`, `frame_index`) are written anew from the rows' places.
const ROW_COLUMNS: [&str; 3] = ["episode_index", "task_index", "timestamp"];

/// The columns a row needs without its images: [`ROW_COLUMNS`] (but the episode's and the
/// task's when the group's statistics give them, `known`), and the features' other values (not
/// the images, nor columns `info` leaves out). Each column read costs a decompressor.
fn light_projection(
    schema: &parquet::schema::types::SchemaDescriptor,
    info: &DatasetInfo,
    known: Known,
) -> ProjectionMask {
    let [episode_column, task_column, _] = ROW_COLUMNS;
    let given = |name: &str| {
        (name == episode_column && known.episode.is_some())
            || (name == task_column && known.task.is_some())
    };
    let wanted = |name: &str| {
        (ROW_COLUMNS.contains(&name) && !given(name))
            || (info.features.iter())
                .any(|f| f.name == name && f.in_steps() && f.dtype != Dtype::Image)
    };
    let roots = (schema.root_schema().get_fields().iter().enumerate())
        .filter(|(_, field)| wanted(field.name()))
        .map(|(i, _)| i);
    ProjectionMask::roots(schema, roots)
}

/// The image bytes of `stored`'s rows (per row, in [`super::read::step_images`] order), read
/// again: for rows first read without them whose group could not be copied after all.
pub(super) fn stored_images(
    stored: &super::copy::StoredGroup,
    info: &DatasetInfo,
) -> Result<Vec<Vec<Vec<u8>>>, ExportError> {
    let path = &stored.file;
    let file = crate::export::bounded::open_regular(path)?;
    let metadata = ArrowReaderMetadata::try_new(stored.metadata.clone(), Default::default())
        .map_err(ExportError::parquet(path))?;
    let reader = ParquetRecordBatchReaderBuilder::new_with_metadata(file, metadata)
        .with_row_groups(vec![stored.row_group])
        .with_batch_size(BATCH_ROWS)
        .build()
        .map_err(ExportError::parquet(path))?;
    let mut images = Vec::new();
    for batch in reader {
        let batch = super::table::fixed_size_lists(batch.map_err(ExportError::Arrow)?);
        images.extend(
            rows_of(&batch, path, info, true, Known::default())?
                .into_iter()
                .map(|r| r.images),
        );
    }
    Ok(images)
}

/// The one episode a row group's `episode_index` statistics say it holds, if they say so.
fn single_episode(group: &parquet::file::metadata::RowGroupMetaData) -> Option<i64> {
    single_value(group, "episode_index")
}

/// The one value of the integer column `name` in `group`, if its statistics say there is one
/// (and no null).
fn single_value(group: &parquet::file::metadata::RowGroupMetaData, name: &str) -> Option<i64> {
    let chunk = (group.columns().iter()).find(|c| c.column_path().string() == name)?;
    match chunk.statistics()? {
        parquet::file::statistics::Statistics::Int64(s) => {
            let (min, max) = (s.min_opt()?, s.max_opt()?);
            let no_nulls = s.null_count_opt() == Some(0);
            (min == max && no_nulls && group.num_rows() > 0).then_some(*min)
        }
        _ => None,
    }
}

/// Decodes a batch of frame rows into steps (`images`: the batch has the image columns, and
/// each row keeps their bytes; `known`: the episode and the task of every row, where the batch
/// leaves their columns out).
fn rows_of(
    batch: &RecordBatch,
    path: &Path,
    info: &DatasetInfo,
    images: bool,
    known: Known,
) -> Result<Vec<Row>, ExportError> {
    let file: std::sync::Arc<Path> = std::sync::Arc::from(path);
    let [episode_column, task_column, timestamp_column] = ROW_COLUMNS;
    let episode = Ints::of(batch, episode_column, known.episode, path)?;
    let task = Ints::of(batch, task_column, known.task, path)?;
    let timestamp = batch
        .column_by_name(timestamp_column)
        .and_then(|c| c.as_any().downcast_ref::<Float32Array>());
    let mut steps: Vec<Row> = (0..batch.num_rows())
        .map(|row| Row {
            episode: episode.value(row),
            task: task.value(row),
            timestamp_secs: timestamp
                .filter(|t| t.is_valid(row))
                .map(|t| f64::from(t.value(row))),
            step: Step::empty(),
            images: Vec::new(),
            file: file.clone(),
        })
        .collect();
    for feature in info.features.iter().filter(|f| f.in_steps()) {
        let name = feature.name.as_str();
        if feature.dtype == Dtype::Image && !images {
            continue;
        }
        if feature.kind == FeatureKind::Other {
            let values = other_values(batch, feature, path)?;
            for (row, value) in steps.iter_mut().zip(values) {
                row.step.other.push(value);
            }
            continue;
        }
        match feature.dtype {
            Dtype::Image => {
                let images = column::<StructArray>(batch, name, path)?;
                let bytes = images
                    .column_by_name("bytes")
                    .and_then(|c| c.as_any().downcast_ref::<BinaryArray>())
                    .ok_or_else(|| invalid(path, format!("{name} has no image bytes")))?;
                for (row, Row { images, .. }) in steps.iter_mut().enumerate() {
                    images.push(bytes.value(row).to_vec());
                }
            }
            _ => {
                let list = column::<FixedSizeListArray>(batch, name, path)?;
                for (row, Row { step, .. }) in steps.iter_mut().enumerate() {
                    let values = vector(list, row);
                    let target: &mut [f32] = match feature.kind {
                        FeatureKind::State => &mut step.state,
                        FeatureKind::Action => &mut step.action,
                        _ => &mut step.environment_state,
                    };
                    if values.len() != target.len() {
                        return Err(invalid(
                            path,
                            format!(
                                "{name} row {row} has {} values, not {}",
                                values.len(),
                                target.len()
                            ),
                        ));
                    }
                    target.copy_from_slice(&values);
                }
            }
        }
    }
    Ok(steps)
}

/// Rows a parquet file may claim per byte of its size. Real files hold far fewer (an episode's
/// row carries a few hundred bytes); a delta-encoded constant column compresses to about a bit
/// per row. A footer claiming more rows, or column chunks beyond the end of the file, is refused
/// before any of it is allocated.
const MAX_ROWS_PER_BYTE: u64 = 64;

/// What is wrong with a parquet footer given the file's size, if anything: row counts that the
/// file cannot hold, column chunks at negative offsets or sizes (the parquet crate asserts on
/// them), outside the file, or together larger than it (chunks never share bytes: thousands of
/// row groups pointing at the same bytes would make every reader's work unbounded).
pub fn footer_problem(
    metadata: &parquet::file::metadata::ParquetMetaData,
    file_bytes: u64,
) -> Option<String> {
    let mut rows: u64 = 0;
    let mut chunk_bytes: u64 = 0;
    for (g, group) in metadata.row_groups().iter().enumerate() {
        let Ok(group_rows) = u64::try_from(group.num_rows()) else {
            return Some(format!("row group {g} claims {} rows", group.num_rows()));
        };
        rows = rows.saturating_add(group_rows);
        for column in group.columns() {
            let start = column
                .dictionary_page_offset()
                .unwrap_or_else(|| column.data_page_offset());
            let (Ok(start), Ok(length)) = (
                u64::try_from(start),
                u64::try_from(column.compressed_size()),
            ) else {
                return Some(format!(
                    "row group {g} places column {} at bytes {start}..+{}",
                    column.column_path(),
                    column.compressed_size()
                ));
            };
            if column.data_page_offset() < 0
                || start.checked_add(length).is_none_or(|end| end > file_bytes)
            {
                return Some(format!(
                    "row group {g} places column {} at bytes {start}..+{length}, beyond the file's {file_bytes}",
                    column.column_path()
                ));
            }
            chunk_bytes = chunk_bytes.saturating_add(length);
        }
    }
    if chunk_bytes > file_bytes {
        return Some(format!(
            "its column chunks claim {chunk_bytes} bytes in a file of {file_bytes} (chunks that share bytes)"
        ));
    }
    if rows > file_bytes.saturating_mul(MAX_ROWS_PER_BYTE) {
        return Some(format!(
            "its footer claims {rows} rows in a file of {file_bytes} bytes"
        ));
    }
    // The file's own count is the sum of its row groups' (readers differ on which they trust).
    let stated = metadata.file_metadata().num_rows();
    (u64::try_from(stated) != Ok(rows))
        .then(|| format!("its footer claims {stated} rows where its row groups hold {rows}"))
}

/// A parquet file and its footer, checked ([`footer_problem`]); `whole`: with its page index
/// and pages' encodings, as a copy of its row groups needs.
pub(super) fn open_parquet_metadata(
    path: &Path,
    whole: bool,
) -> Result<(File, parquet::arrow::arrow_reader::ArrowReaderMetadata), ExportError> {
    let file = crate::export::bounded::open_regular(path)?;
    let file_bytes = file.metadata().map_err(ExportError::io(path))?.len();
    let policy = if whole {
        parquet::file::metadata::PageIndexPolicy::Optional
    } else {
        parquet::file::metadata::PageIndexPolicy::Skip
    };
    // For copying, the whole footer as written: the page index, and the pages' encodings
    // listed (not summed up as a mask, which a writer cannot write back).
    let options = parquet::arrow::arrow_reader::ArrowReaderOptions::new()
        .with_page_index_policy(policy)
        .with_encoding_stats_as_mask(!whole);
    let metadata = parquet::arrow::arrow_reader::ArrowReaderMetadata::load(&file, options)
        .map_err(ExportError::parquet(path))?;
    if let Some(problem) = footer_problem(metadata.metadata(), file_bytes) {
        return Err(invalid(path, problem));
    }
    Ok((file, metadata))
}

pub(super) fn column<'a, T: 'static>(
    batch: &'a RecordBatch,
    name: &str,
    path: &Path,
) -> Result<&'a T, ExportError> {
    batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<T>())
        .ok_or_else(|| {
            ExportError::InvalidEpisode(format!(
                "{}: column {name} missing or of the wrong type",
                path.display()
            ))
        })
}

pub(super) fn vector(list: &FixedSizeListArray, row: usize) -> Vec<f32> {
    let values = list.value(row);
    values
        .as_any()
        .downcast_ref::<Float32Array>()
        .map(|v| v.values().to_vec())
        .unwrap_or_default()
}

pub(super) fn invalid(path: &Path, problem: impl Into<String>) -> ExportError {
    ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Each row's value of an [`FeatureKind::Other`] feature, as stored.
pub(super) fn other_values(
    batch: &RecordBatch,
    feature: &FeatureSpec,
    path: &Path,
) -> Result<Vec<FeatureValue>, ExportError> {
    let name = feature.name.as_str();
    let column = batch
        .column_by_name(name)
        .ok_or_else(|| invalid(path, format!("column {name} is missing")))?;
    let n: usize = feature.shape.iter().product();
    let rows = batch.num_rows();
    let bad = || {
        invalid(
            path,
            format!(
                "column {name} is not a {:?} of shape {:?}",
                feature.dtype, feature.shape
            ),
        )
    };
    let any = column.as_any();
    let (values, offset): (&dyn Array, usize) = match any.downcast_ref::<FixedSizeListArray>() {
        Some(list) if list.value_length() as usize == n => {
            (list.values().as_ref(), list.offset() * n)
        }
        Some(_) => return Err(bad()),
        None if n == 1 => (column.as_ref(), 0),
        None if matches!(feature.dtype, Dtype::Image | Dtype::String) => (column.as_ref(), 0),
        None => return Err(bad()),
    };
    let chunk = |row: usize| offset + row * n..offset + (row + 1) * n;
    Ok(match feature.dtype {
        Dtype::Image => {
            let images = any.downcast_ref::<StructArray>().ok_or_else(bad)?;
            let bytes = images
                .column_by_name("bytes")
                .and_then(|c| c.as_any().downcast_ref::<BinaryArray>())
                .ok_or_else(bad)?;
            (0..rows)
                .map(|r| FeatureValue::Image(bytes.value(r).to_vec()))
                .collect()
        }
        Dtype::Float32 | Dtype::Float64 => {
            let singles = values.as_any().downcast_ref::<Float32Array>();
            let doubles = values.as_any().downcast_ref::<Float64Array>();
            (0..rows)
                .map(|r| match (feature.dtype, singles, doubles) {
                    (Dtype::Float32, Some(a), _) => {
                        Ok(FeatureValue::Float32(a.values()[chunk(r)].to_vec()))
                    }
                    // float64 read as float32 (`--cast float32`).
                    (Dtype::Float32, _, Some(a)) => Ok(FeatureValue::Float32(
                        a.values()[chunk(r)].iter().map(|&v| v as f32).collect(),
                    )),
                    (Dtype::Float64, _, Some(a)) => {
                        Ok(FeatureValue::Float64(a.values()[chunk(r)].to_vec()))
                    }
                    _ => Err(bad()),
                })
                .collect::<Result<_, _>>()?
        }
        Dtype::Int64 => {
            let a = values
                .as_any()
                .downcast_ref::<Int64Array>()
                .ok_or_else(bad)?;
            (0..rows)
                .map(|r| FeatureValue::Int64(a.values()[chunk(r)].to_vec()))
                .collect()
        }
        Dtype::String => {
            let text = |r: usize| {
                if let Some(a) = any.downcast_ref::<StringArray>() {
                    Some(a.value(r).to_string())
                } else {
                    let a = any.downcast_ref::<LargeStringArray>()?;
                    Some(a.value(r).to_string())
                }
            };
            (0..rows)
                .map(|r| text(r).map(FeatureValue::Text).ok_or_else(bad))
                .collect::<Result<_, _>>()?
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{FeatureSet, standard_features};

    /// A reader told which episodes it takes has nothing of the others' row groups read from
    /// the disk: its read-ahead asks for the groups taken ahead of it alone, and reading a
    /// group in order reads nothing past it (`mincore` says which pages are cached).
    #[cfg(target_os = "linux")]
    #[test]
    fn the_groups_of_episodes_not_taken_stay_on_the_disk() {
        use crate::files::page_cache;
        use arrow_array::{ArrayRef, BinaryArray, Int64Array, RecordBatch};
        let root = std::env::temp_dir().join(format!("surgvla-taking-{}", std::process::id()));
        std::fs::create_dir_all(&root).expect("folder");
        let path = root.join("file-000.parquet");
        // Five episodes, a row group of 1.5 MiB each (bytes no codec shrinks).
        let mut rng = crate::rng::SplitMix64::new(48);
        let batches: Vec<RecordBatch> = (0..5i64)
            .map(|episode| {
                let blob: Vec<u8> = (0..3 << 19).map(|_| rng.next_u64() as u8).collect();
                let index: ArrayRef = std::sync::Arc::new(Int64Array::from(vec![episode]));
                let blob: ArrayRef = std::sync::Arc::new(BinaryArray::from(vec![blob.as_slice()]));
                RecordBatch::try_from_iter([("episode_index", index), ("blob", blob)])
                    .expect("batch")
            })
            .collect();
        let mut bytes = Vec::new();
        let mut writer =
            parquet::arrow::ArrowWriter::try_new(&mut bytes, batches[0].schema(), None)
                .expect("writer");
        for batch in &batches {
            writer.write(batch).expect("write");
            writer.flush().expect("a row group");
        }
        writer.close().expect("footer");
        std::fs::write(&path, &bytes).expect("file");
        page_cache::drop(&File::open(&path).expect("open"));
        let mut rows = DataRows::new(vec![path.clone()]);
        rows.taking_only(std::sync::Arc::new([0, 3, 4].into_iter().collect()));
        assert_eq!(rows.next().expect("opens"), Some(Next::Episode(0)));
        let open = rows.open.as_mut().expect("open");
        let spans: Vec<_> = (open.metadata.metadata().row_groups().iter())
            .map(group_span)
            .collect();
        let middle = |k: usize| (spans[k].start + spans[k].end) / 2;
        // Group 0 read as the reader reads it: its read-ahead asked for, then in order.
        open.read_ahead(0);
        let mut buffer = vec![0u8; 64 << 10];
        let mut at = spans[0].start;
        while at < spans[0].end {
            let n = buffer.len().min((spans[0].end - at) as usize);
            crate::files::read_exact_at(&open.file, &mut buffer[..n], at).expect("read");
            at += n as u64;
        }
        let file = File::open(&path).expect("open");
        assert!(
            page_cache::comes_into(&file, middle(3), 20),
            "episode 3 read ahead"
        );
        for k in [1, 2] {
            assert!(
                !page_cache::comes_into(&file, middle(k), 1),
                "episode {k}'s group, not taken, was read"
            );
        }
        std::fs::remove_dir_all(&root).expect("removed");
    }

    /// A row group's span covers each of its column chunks and no other group's.
    #[test]
    fn a_row_groups_span_covers_its_chunks_and_no_other_groups() {
        use arrow_array::{ArrayRef, Int64Array, RecordBatch};
        let a: ArrayRef = std::sync::Arc::new(Int64Array::from_iter_values(0..100));
        let b: ArrayRef =
            std::sync::Arc::new(Int64Array::from_iter_values((0..100).map(|v| v * 7)));
        let batch = RecordBatch::try_from_iter([("a", a), ("b", b)]).expect("batch");
        let mut bytes = Vec::new();
        let mut writer =
            parquet::arrow::ArrowWriter::try_new(&mut bytes, batch.schema(), None).expect("writer");
        for _ in 0..3 {
            writer.write(&batch).expect("write");
            writer.flush().expect("a row group");
        }
        writer.close().expect("footer");
        let metadata = parquet::file::metadata::ParquetMetaDataReader::new()
            .parse_and_finish(&bytes::Bytes::from(bytes.clone()))
            .expect("footer");
        let spans: Vec<_> = metadata.row_groups().iter().map(group_span).collect();
        assert_eq!(spans.len(), 3);
        for (group, span) in metadata.row_groups().iter().zip(&spans) {
            for chunk in group.columns() {
                let (start, size) = chunk.byte_range();
                assert!(span.start <= start && start + size <= span.end, "{span:?}");
            }
        }
        assert!(
            spans.windows(2).all(|w| w[0].end <= w[1].start),
            "{spans:?}"
        );
        assert!(spans[0].start >= 4 && spans[2].end <= bytes.len() as u64);
    }

    #[test]
    fn rows_read_without_images_leave_out_the_images_and_the_indices_made_anew() {
        let features = standard_features(8, 8, FeatureSet::default());
        let info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 5, "r", features);
        let arrow = super::super::table::frame_schema(&info.features);
        let schema = parquet::arrow::ArrowSchemaConverter::new()
            .convert(&arrow)
            .expect("parquet schema");
        let read = |episode: Option<i64>, task: Option<i64>| -> Vec<String> {
            let mask = light_projection(&schema, &info, Known { episode, task });
            (0..schema.num_columns())
                .filter(|&leaf| mask.leaf_included(leaf))
                .map(|leaf| schema.column(leaf).path().parts()[0].clone())
                .collect()
        };
        let vectors = [
            "observation.state",
            "observation.environment_state",
            "action",
            "timestamp",
        ];
        let indices = ["episode_index", "task_index"];
        assert_eq!(read(None, None), [&vectors[..], &indices].concat());
        // A group whose statistics give its episode or its task does not read them.
        assert_eq!(
            read(Some(3), None),
            [&vectors[..], &["task_index"]].concat()
        );
        assert_eq!(
            read(None, Some(1)),
            [&vectors[..], &["episode_index"]].concat()
        );
        assert_eq!(read(Some(3), Some(1)), vectors);
    }
}
