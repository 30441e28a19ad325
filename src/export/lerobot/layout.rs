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

use super::LeRobotVersion;
use super::table::{EpisodeRow, episodes_batch, tasks_batch};
use crate::export::ExportError;
use crate::export::dir::FileCounter;
use crate::export::video::video_path;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Everything the metadata files are made of.
pub(super) struct Metadata<'a> {
    pub tasks: &'a [String],
    pub episodes: &'a [EpisodeRow],
    /// stats.json's object.
    pub stats: Value,
    /// surgvla.json's object.
    pub surgvla: Value,
    /// info.json's object as v3.0 has it.
    pub info: Value,
    pub chunks_size: u64,
    /// The video feature's key, in video mode.
    pub video_key: Option<&'a str>,
}

fn pretty(name: &str, value: &Value) -> Result<Vec<u8>, ExportError> {
    serde_json::to_vec_pretty(value).map_err(|source| ExportError::Json {
        path: PathBuf::from("meta").join(name),
        source,
    })
}

fn json_lines(values: impl Iterator<Item = Value>) -> Vec<u8> {
    values
        .map(|v| format!("{v}\n"))
        .collect::<String>()
        .into_bytes()
}

/// A whole parquet file in memory (snappy, one row group).
fn parquet_bytes(name: &str, batch: &arrow_array::RecordBatch) -> Result<Vec<u8>, ExportError> {
    let parquet_error = ExportError::parquet(Path::new(name));
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .build();
    let mut bytes = Vec::new();
    let mut writer =
        ArrowWriter::try_new(&mut bytes, batch.schema(), Some(props)).map_err(&parquet_error)?;
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
    /// so it checkpoints every 64 episodes (the checkpoint holds every episode's row).
    pub(super) fn checkpoint_due(self, episodes: usize) -> bool {
        self == LeRobotVersion::V30 || episodes % 64 == 0
    }

    /// The metadata files (relative path, bytes), `meta/info.json` last.
    pub(super) fn metadata_files(
        self,
        m: &Metadata<'_>,
    ) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        let mut files = Vec::new();
        let mut info = m.info.clone();
        match self {
            LeRobotVersion::V30 => {
                files.push((
                    "meta/tasks.parquet".to_string(),
                    parquet_bytes("meta/tasks.parquet", &tasks_batch(m.tasks)?)?,
                ));
                let episodes = "meta/episodes/chunk-000/file-000.parquet";
                files.push((
                    episodes.to_string(),
                    parquet_bytes(episodes, &episodes_batch(m.episodes, m.video_key)?)?,
                ));
            }
            LeRobotVersion::V21 => {
                let rows = m.episodes.iter();
                files.push((
                    "meta/episodes.jsonl".into(),
                    json_lines(rows.clone().map(|e| {
                        let mut line = json!({"episode_index": e.episode_index, "tasks": [e.task], "length": e.length});
                        for (key, value) in e.provenance.columns() {
                            line[key] = value;
                        }
                        line
                    })),
                ));
                files.push((
                    "meta/tasks.jsonl".into(),
                    json_lines(
                        m.tasks
                            .iter()
                            .enumerate()
                            .map(|(i, t)| json!({"task_index": i, "task": t})),
                    ),
                ));
                files.push((
                    "meta/episodes_stats.jsonl".into(),
                    json_lines(
                        rows.map(|e| json!({"episode_index": e.episode_index, "stats": e.stats})),
                    ),
                ));
                let chunks = (m.episodes.len() as u64).div_ceil(m.chunks_size.max(1));
                info["codebase_version"] = json!("v2.1");
                info["total_chunks"] = json!(chunks);
                info["total_videos"] = json!(if m.video_key.is_some() {
                    m.episodes.len()
                } else {
                    0
                });
                info["data_path"] =
                    json!("data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet");
                if m.video_key.is_some() {
                    info["video_path"] = json!(
                        "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
                    );
                }
                if let Some(object) = info.as_object_mut() {
                    object.remove("data_files_size_in_mb");
                    object.remove("video_files_size_in_mb");
                }
            }
        }
        files.push(("meta/stats.json".into(), pretty("stats.json", &m.stats)?));
        files.push((
            "meta/surgvla.json".into(),
            pretty("surgvla.json", &m.surgvla)?,
        ));
        files.push(("meta/info.json".into(), pretty("info.json", &info)?));
        Ok(files)
    }
}
