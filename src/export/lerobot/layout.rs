//! The differences between the LeRobot v3.0 and v2.1 layouts, in one place: file names, when a
//! data file closes, how often the writer checkpoints, and the metadata files.
//!
//! ```text
//! v3.0                                            v2.1
//! data/chunk-CCC/file-FFF.parquet (rolled by size) data/chunk-CCC/episode_EEEEEE.parquet
//! videos/KEY/chunk-CCC/file-FFF.mp4               videos/chunk-CCC/KEY/episode_EEEEEE.mp4
//! meta/tasks.parquet, meta/episodes/...parquet    meta/tasks.jsonl, episodes.jsonl,
//!                                                 episodes_stats.jsonl
//! meta/stats.json, meta/surgvla.json, meta/info.json (last) in both
//! ```

use super::copy::write_group;
use super::meta::StatsJson;
use super::options::LeRobotVersion;
use super::table::{EpisodeRow, episodes_batch, tasks_batch};
use crate::export::dir::{DatasetDir, FileCounter};
use crate::export::error::ExportError;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use serde_json::{Value, json};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Everything the metadata files are made of.
pub(super) struct Metadata<'a> {
    pub tasks: &'a [String],
    /// How many episodes the dataset holds.
    pub episodes: u64,
    /// stats.json's object.
    pub stats: StatsJson,
    /// surgvla.json's object.
    pub surgvla: Value,
    /// info.json as v3.0 has it.
    pub info: super::meta::InfoJson,
    pub chunks_size: u64,
    /// The video features' keys.
    pub video_keys: &'a [String],
}

fn pretty(name: &str, value: &impl serde::Serialize) -> Result<Vec<u8>, ExportError> {
    serde_json::to_vec_pretty(value).map_err(|source| ExportError::Json {
        path: PathBuf::from("meta").join(name),
        source,
    })
}

/// One compact JSON line per value.
fn json_lines<T: serde::Serialize>(
    name: &str,
    values: impl Iterator<Item = T>,
) -> Result<Vec<u8>, ExportError> {
    let mut out = Vec::new();
    for value in values {
        serde_json::to_writer(&mut out, &value).map_err(|source| ExportError::Json {
            path: PathBuf::from("meta").join(name),
            source,
        })?;
        out.push(b'\n');
    }
    Ok(out)
}

/// How the metadata tables are written: snappy, the parquet defaults otherwise.
fn snappy() -> WriterProperties {
    WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .build()
}

/// A whole parquet file in memory (snappy, one row group).
fn parquet_bytes(name: &str, batch: &arrow_array::RecordBatch) -> Result<Vec<u8>, ExportError> {
    let parquet_error = ExportError::parquet(Path::new(name));
    let mut bytes = Vec::new();
    let mut writer =
        ArrowWriter::try_new(&mut bytes, batch.schema(), Some(snappy())).map_err(&parquet_error)?;
    writer.write(batch).map_err(&parquet_error)?;
    writer.close().map_err(&parquet_error)?;
    Ok(bytes)
}

impl LeRobotVersion {
    /// (chunk, file) of the next data or video file: v3.0 numbers files by `counter`; v2.1 has
    /// one file per episode, numbered by the episode index.
    pub(super) fn next_location(self, counter: &mut FileCounter, episode: u64) -> (u64, u64) {
        let counted = counter.take();
        match self {
            LeRobotVersion::V30 => counted,
            LeRobotVersion::V21 => (episode / counter.chunks_size, episode),
        }
    }

    pub(super) fn data_path(self, chunk: u64, file: u64) -> String {
        match self {
            LeRobotVersion::V30 => format!("data/chunk-{chunk:03}/file-{file:03}.parquet"),
            LeRobotVersion::V21 => format!("data/chunk-{chunk:03}/episode_{file:06}.parquet"),
        }
    }

    pub(super) fn video_path(self, key: &str, chunk: u64, file: u64) -> String {
        match self {
            LeRobotVersion::V30 => video_path(key, chunk, file),
            LeRobotVersion::V21 => format!("videos/chunk-{chunk:03}/{key}/episode_{file:06}.mp4"),
        }
    }

    /// Whether a file of `bytes` closes now (v2.1: after every episode).
    pub(super) fn file_is_full(self, bytes: u64, limit_bytes: u64) -> bool {
        self == LeRobotVersion::V21 || bytes >= limit_bytes
    }

    /// Whether the writer records a checkpoint after closing its files with `episodes` written:
    /// v3.0 closes a file every ~100 MB and checkpoints each time; v2.1 closes one per episode,
    /// so it checkpoints every 64 episodes (each checkpoint syncs files and rewrites the
    /// statistics' state, a few MB).
    pub(super) fn checkpoint_due(self, episodes: u64) -> bool {
        self == LeRobotVersion::V30 || episodes.is_multiple_of(64)
    }

    /// Writes the metadata files, `meta/info.json` last, from `m` and the episode rows in
    /// order (streamed: at most [`ROWS_PER_GROUP`] rows are in memory); returns (files, bytes).
    pub(super) fn write_metadata(
        self,
        dir: &mut DatasetDir,
        m: &Metadata<'_>,
        rows: impl Iterator<Item = Result<EpisodeRow, ExportError>> + Send,
    ) -> Result<(u64, u64), ExportError> {
        let mut files = Vec::new();
        let mut written = (0u64, 0u64);
        let mut info = m.info.clone();
        match self {
            LeRobotVersion::V30 => {
                files.push((
                    "meta/tasks.parquet".to_string(),
                    parquet_bytes("meta/tasks.parquet", &tasks_batch(m.tasks)?)?,
                ));
                let bytes = write_episodes_parquet(dir, EPISODES_V30, rows, m.video_keys)?;
                written = (written.0 + 1, written.1 + bytes);
            }
            LeRobotVersion::V21 => {
                let bytes = write_episodes_jsonl(dir, rows)?;
                written = (written.0 + 2, written.1 + bytes);
                files.push((
                    "meta/tasks.jsonl".into(),
                    json_lines(
                        "tasks.jsonl",
                        m.tasks
                            .iter()
                            .enumerate()
                            .map(|(i, t)| super::meta::TaskLine {
                                task_index: Some(i as i64),
                                task: Some(t.clone()),
                            }),
                    )?,
                ));
                let chunks = m.episodes.div_ceil(m.chunks_size.max(1));
                info.codebase_version = Some("v2.1".into());
                info.total_chunks = Some(chunks);
                info.total_videos = Some(m.episodes * m.video_keys.len() as u64);
                info.data_path = Some(
                    "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet".into(),
                );
                if !m.video_keys.is_empty() {
                    info.video_path = Some(
                        "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
                            .into(),
                    );
                }
                info.data_files_size_in_mb = None;
                info.video_files_size_in_mb = None;
            }
        }
        files.push(("meta/stats.json".into(), pretty("stats.json", &m.stats)?));
        if !m.surgvla.is_null() {
            files.push((
                "meta/surgvla.json".into(),
                pretty("surgvla.json", &m.surgvla)?,
            ));
        }
        files.push(("meta/info.json".into(), pretty("info.json", &info)?));
        for (relative, bytes) in files {
            written = (
                written.0 + 1,
                written.1 + dir.write_atomically(&relative, &bytes)?,
            );
        }
        Ok(written)
    }
}

/// The v3.0 episodes table (one file: LeRobot rolls it at its data file size, which ~100
/// bytes a row reach only past a million episodes).
const EPISODES_V30: &str = "meta/episodes/chunk-000/file-000.parquet";

/// Rows of the episodes table held in memory at once: one row group each.
const ROWS_PER_GROUP: usize = 256;

fn write_episodes_parquet(
    dir: &mut DatasetDir,
    relative: &str,
    mut rows: impl Iterator<Item = Result<EpisodeRow, ExportError>> + Send,
    video_keys: &[String],
) -> Result<u64, ExportError> {
    let (file, pending) = dir.create_file(relative)?;
    let parquet_error = ExportError::parquet(&pending.path);
    let mut next_batch = || -> Result<arrow_array::RecordBatch, ExportError> {
        let group = rows
            .by_ref()
            .take(ROWS_PER_GROUP)
            .collect::<Result<Vec<_>, _>>()?;
        episodes_batch(&group, video_keys)
    };
    // The first batch (empty when there are no episodes) gives the schema.
    let mut batch = next_batch()?;
    let schema = batch.schema();
    let writer =
        ArrowWriter::try_new(file, schema.clone(), Some(snappy())).map_err(&parquet_error)?;
    let (mut writer, factory) = writer.into_serialized_writer().map_err(&parquet_error)?;
    let mut groups = 0;
    loop {
        let last = batch.num_rows() < ROWS_PER_GROUP;
        // The next batch is made while this one is written.
        let (written, next) = rayon::join(
            || write_group(&mut writer, &factory, &schema, &batch, groups),
            || (!last).then(&mut next_batch).transpose(),
        );
        written.map_err(&parquet_error)?;
        groups += 1;
        match next? {
            Some(next) if next.num_rows() > 0 => batch = next,
            _ => break,
        }
    }
    writer.close().map_err(&parquet_error)?;
    dir.commit(pending)
}

/// v2.1's `episodes.jsonl` and `episodes_stats.jsonl`, one line per episode, in one pass.
fn write_episodes_jsonl(
    dir: &mut DatasetDir,
    rows: impl Iterator<Item = Result<EpisodeRow, ExportError>>,
) -> Result<u64, ExportError> {
    let (episodes, episodes_pending) = dir.create_file("meta/episodes.jsonl")?;
    let (stats, stats_pending) = dir.create_file("meta/episodes_stats.jsonl")?;
    let (mut episodes, mut stats) = (BufWriter::new(episodes), BufWriter::new(stats));
    for row in rows {
        let e = row?;
        let mut line =
            json!({"episode_index": e.episode_index, "tasks": e.tasks, "length": e.length});
        for (key, value) in e
            .provenance
            .iter()
            .flat_map(super::table::Provenance::columns)
        {
            line[key] = value;
        }
        for (key, value) in (e.fields.iter()).filter(|(k, _)| super::table::free_field_name(k)) {
            line[key.as_str()] = value.clone();
        }
        for (key, value) in &e.pixel_stats {
            let value = serde_json::from_str(value.get()).map_err(|source| ExportError::Json {
                path: episodes_pending.path.clone(),
                source,
            })?;
            line[format!("{}{key}", super::table::PIXEL_STATS)] = value;
        }
        writeln!(episodes, "{line}").map_err(ExportError::io(&episodes_pending.path))?;
        let line = json!({"episode_index": e.episode_index, "stats": e.stats});
        writeln!(stats, "{line}").map_err(ExportError::io(&stats_pending.path))?;
    }
    episodes.into_inner().map_err(|e| ExportError::Io {
        path: episodes_pending.path.clone(),
        source: e.into_error(),
    })?;
    stats.into_inner().map_err(|e| ExportError::Io {
        path: stats_pending.path.clone(),
        source: e.into_error(),
    })?;
    Ok(dir.commit(episodes_pending)? + dir.commit(stats_pending)?)
}

/// The path of a v3.0 video file relative to the dataset root.
pub(super) fn video_path(key: &str, chunk: u64, file: u64) -> String {
    format!("videos/{key}/chunk-{chunk:03}/file-{file:03}.mp4")
}

/// The card's loading snippet for a dataset of `version`: lerobot's own loader (v3.0 since
/// lerobot 0.4, v2.1 before it).
pub(super) fn loading_snippet(version: LeRobotVersion) -> String {
    let (module, lerobot) = match version {
        LeRobotVersion::V30 => ("lerobot.datasets.lerobot_dataset", "lerobot >= 0.4"),
        LeRobotVersion::V21 => ("lerobot.common.datasets.lerobot_dataset", "lerobot 0.3"),
    };
    format!(
        "With {lerobot}, from this folder:\n\n```python\nfrom {module} import LeRobotDataset\n\ndataset = LeRobotDataset(\"local/surgvla\", root=\".\")\nframe = dataset[0]  # images as (C, H, W) floats in [0, 1], observation.state, action, task\n```\n"
    )
}
