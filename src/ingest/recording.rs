//! What every recording reader yields, whatever the container: [`Channel`]s (a topic, its
//! message type, the type's definition when the recording carries one, and the wire format of
//! its messages) and [`RawMessage`]s in recording order; and [`BagError`], a recording that
//! cannot be read, naming the file and the byte. Readers implement [`MessageReader`];
//! [`Messages`] makes any of them an iterator that stops after an error.

use crate::ingest::decode::Wire;
use std::collections::BTreeMap;
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

/// A recording reader: its messages in recording order, and the channels seen so far.
pub trait MessageReader: Send {
    /// The next message; None at the end.
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError>;
    /// The channels seen so far (every one before its first message).
    fn channels(&self) -> &BTreeMap<u32, Channel>;
}

impl<R: MessageReader + ?Sized> MessageReader for Box<R> {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        (**self).next_message()
    }

    fn channels(&self) -> &BTreeMap<u32, Channel> {
        (**self).channels()
    }
}

/// A reader's messages as an iterator: after an error, nothing more.
pub struct Messages<R> {
    reader: R,
    failed: bool,
}

impl<R: MessageReader> Messages<R> {
    pub fn new(reader: R) -> Messages<R> {
        Messages {
            reader,
            failed: false,
        }
    }

    /// The channels seen so far (every one before its first message).
    pub fn channels(&self) -> &BTreeMap<u32, Channel> {
        self.reader.channels()
    }
}

impl<R: MessageReader> Iterator for Messages<R> {
    type Item = Result<RawMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let next = self.reader.next_message();
        self.failed = next.is_err();
        next.transpose()
    }
}
