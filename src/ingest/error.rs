//! [`IngestError`]: why a recording could not be ingested, naming the file, the topic and the
//! message.

use crate::ingest::decode::DecodeError;
use crate::ingest::msgdef::DefinitionError;
use crate::ingest::recording::BagError;
use std::path::PathBuf;

/// Why a recording could not be ingested.
#[derive(Debug, thiserror::Error)]
pub enum IngestError {
    /// What was asked cannot be done (an offset for a topic the preset does not read).
    #[error("{0}")]
    Usage(String),
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error("{path}: topic {topic}: the definition of {type_name}")]
    Definition {
        path: PathBuf,
        topic: String,
        type_name: String,
        #[source]
        source: Box<DefinitionError>,
    },
    #[error("{path}: topic {topic}, message {index}")]
    Decode {
        path: PathBuf,
        topic: String,
        index: usize,
        #[source]
        source: Box<DecodeError>,
    },
    #[error(
        "{path}: topic {topic}, message {index}: no header stamp (zero, or no header): use --clock receive to synchronise on the bag's receive times"
    )]
    NoStamp {
        path: PathBuf,
        topic: String,
        index: usize,
    },
    #[error("{path}: the frame at {time_ns} ns: {problem}")]
    Frame {
        path: PathBuf,
        time_ns: i64,
        problem: String,
    },
    #[error("{path}")]
    Sync {
        path: PathBuf,
        #[source]
        source: crate::ingest::sync::TooManyFrames,
    },
    #[error("{path} has no message on {topic}")]
    MissingTopic { path: PathBuf, topic: String },
    /// The reading thread was asked to stop (the source dropped early); never shown.
    #[error("the reading was stopped")]
    Stopped,
    /// The reading thread ended without a word before the input's last episode (it panicked).
    #[error("{path}: the reading stopped with {episodes} episodes to come")]
    ReadingEnded { path: PathBuf, episodes: usize },
    #[error("{path}: topic {topic} carries {first} and {second}: one type per topic")]
    TwoTypes {
        path: PathBuf,
        topic: String,
        first: String,
        second: String,
    },
}

impl IngestError {
    /// The `index`-th message of `topic` in `path` could not be decoded.
    pub fn decode(path: &std::path::Path, topic: &str, index: usize, source: DecodeError) -> Self {
        IngestError::Decode {
            path: path.to_path_buf(),
            topic: topic.to_string(),
            index,
            source: Box::new(source),
        }
    }
}

impl crate::error::HasKind for IngestError {
    /// A recording that cannot be read or decoded is invalid data (exit 1); a usage error
    /// (exit 2) is what was asked.
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            IngestError::Usage(_) => crate::error::ErrorKind::Usage,
            _ => crate::error::ErrorKind::Failed,
        }
    }
}
