//! Dataset exporters.
//!
//! Every exporter has one shape: options -> `Writer::create` -> one [`EpisodeSink::write_episode`]
//! per episode -> [`EpisodeSink::finish`] returning a [`Summary`]. Exporters never depend on the
//! simulator: they see [`crate::episode::Episode`]s only. Memory stays bounded: nothing grows
//! with the number of episodes except a small per-episode index.
//!
//! - [`lerobot`]: LeRobot v3.0 (parquet + metadata, images embedded as PNG/TIFF).

pub mod lerobot;
pub mod stats;
pub mod tiff;
pub mod video;

use crate::episode::Episode;
use std::path::{Path, PathBuf};

/// What went wrong while exporting, naming the file where there is one.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Parquet {
        path: PathBuf,
        source: parquet::errors::ParquetError,
    },
    #[error("building arrow data: {0}")]
    Arrow(#[from] arrow_schema::ArrowError),
    #[error("{path} already holds a dataset or other files; choose an empty or new directory")]
    NotEmpty { path: PathBuf },
    #[error("cannot resume {path}: {reason}")]
    NotResumable { path: PathBuf, reason: String },
    #[error("invalid episode: {0}")]
    InvalidEpisode(String),
    #[error("encoding {what}: {message}")]
    Encode { what: String, message: String },
    #[error("internal error: {0}")]
    Internal(String),
}

impl ExportError {
    pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> ExportError {
        let path = path.into();
        move |source| ExportError::Io { path, source }
    }
}

/// What an exporter wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub episodes: u64,
    pub frames: u64,
    pub files: u64,
    pub bytes: u64,
}

/// Seconds an exporter spent, for reports (never written into a dataset).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SinkTiming {
    /// Encoding images, video and statistics (wall seconds, parallel inside).
    pub encode_secs: f64,
    /// Building tables and writing files.
    pub write_secs: f64,
}

/// Receives episodes one at a time, in episode-index order.
pub trait EpisodeSink {
    fn write_episode(&mut self, episode: &Episode) -> Result<(), ExportError>;
    /// Writes consecutive episodes (a sink may work on them in parallel; output is as if they
    /// were written one by one).
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError> {
        episodes.iter().try_for_each(|e| self.write_episode(e))
    }
    /// Time spent so far.
    fn timing(&self) -> SinkTiming {
        SinkTiming::default()
    }
    /// Completes the dataset: after this returns Ok, it is consistent and loadable.
    fn finish(self: Box<Self>) -> Result<Summary, ExportError>;
}

/// Writes `bytes` to `path` through a temporary name and a rename, so a crash never leaves a
/// half-written file under the final name.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), ExportError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
    }
    let temporary = temporary_name(path);
    std::fs::write(&temporary, bytes).map_err(ExportError::io(&temporary))?;
    std::fs::rename(&temporary, path).map_err(ExportError::io(path))
}

/// The temporary name of `path` while it is being written (`.name.partial`).
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.partial"))
}
