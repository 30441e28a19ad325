//! One reader for any recording: [`Recording`] opens a ROS 2 bag folder, or a ROS 1 bag or an
//! MCAP file by its first bytes and yields the same [`RawMessage`]s and [`Channel`]s either way.

use crate::ingest::mcap::McapRecording;
use crate::ingest::recording::{BagError, MessageReader, Messages};
use crate::ingest::ros1::{MAGIC as ROS1_MAGIC, Ros1Bag};
use crate::ingest::rosbag2::Rosbag2;
use std::io::Read;
use std::path::Path;

/// The first bytes of an MCAP file.
const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// A recording file being read, whatever its container.
pub type Recording = Messages<Box<dyn MessageReader>>;

/// A recording to open: its path, and where a file SQLite must read uncompressed may be
/// decompressed (see [`Rosbag2::open_with`]).
#[derive(Clone, Copy, Debug)]
pub struct BagInput<'a> {
    pub path: &'a Path,
    pub scratch: Option<&'a Path>,
}

impl<'a> BagInput<'a> {
    pub fn new(path: &'a Path, scratch: Option<&'a Path>) -> Self {
        BagInput { path, scratch }
    }
}

impl Recording {
    /// Opens the input as the recording its first bytes say it is.
    pub fn open(input: BagInput<'_>) -> Result<Recording, BagError> {
        let path = input.path;
        if path.is_dir() {
            let bag = Rosbag2::open_with(path, input.scratch.map(Path::to_path_buf))?;
            let bag: Box<dyn MessageReader> = Box::new(bag);
            return Ok(Messages::new(bag));
        }
        let mut start = [0u8; 13];
        let read = crate::files::open_regular(path)
            .and_then(|mut file| {
                let mut read = 0;
                while read < start.len() {
                    match file.read(&mut start[read..])? {
                        0 => break,
                        n => read += n,
                    }
                }
                Ok(read)
            })
            .map_err(|source| BagError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let start = &start[..read];
        let reader: Box<dyn MessageReader> = if start.starts_with(ROS1_MAGIC) {
            Box::new(Ros1Bag::open(path)?)
        } else if start.starts_with(MCAP_MAGIC) {
            Box::new(McapRecording::open(path)?)
        } else {
            return Err(BagError::Damaged {
                path: path.to_path_buf(),
                offset: 0,
                problem: "neither a ROS 1 bag (#ROSBAG V2.0) nor an MCAP file".into(),
            });
        };
        Ok(Messages::new(reader))
    }
}
