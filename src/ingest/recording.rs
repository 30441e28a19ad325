//! What every recording reader yields, whatever the container: [`Channel`]s (a topic, its
//! message type, the type's definition when the recording carries one, and the wire format of
//! its messages) and [`RawMessage`]s in recording order; and [`BagError`], a recording that
//! cannot be read, naming the file and the byte.

use crate::ingest::decode::Wire;
use std::path::PathBuf;

/// A recording that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("reading {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}, byte {offset}: {problem}")]
    Damaged {
        path: PathBuf,
        offset: u64,
        problem: String,
    },
}

/// What a channel (a ROS 1 connection, an MCAP channel, a rosbag2 topic) carries.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Channel {
    pub topic: String,
    /// `pkg/Type` (ROS 2's `pkg/msg/Type` as recorded).
    pub type_name: String,
    /// The type's definition with its dependencies ([`crate::ingest::msgdef`]); None when the
    /// recording carries none (built-in definitions then apply).
    pub definition: Option<String>,
    pub wire: Wire,
}

/// One message as stored: its channel, the time the recorder received it, its bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawMessage {
    /// The channel's id in its recording.
    pub connection: u32,
    /// Receive (log) time, nanoseconds since the epoch.
    pub receive_ns: i64,
    pub data: Vec<u8>,
}
