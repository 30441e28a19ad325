//! Media codecs: the bytes of one image or one video stream, below any dataset.
//!
//! - [`image`]: 8-bit and 16-bit PNG, baseline JPEG, and reading them back.
//! - [`png_rows`]: a PNG checked and inflated to its filtered rows, unfiltered on demand
//!   (validate's full pass).
//! - [`tiff`]: float32 grey TIFF (depth in metres, as LeRobot stores it).
//! - [`video`]: AV1 (rav1e) and H.264 (openh264) encoding, and the MP4 muxer.
//! - [`demux`]: an MP4 file's video samples read back without decoding (re_mp4), bounded first
//!   by [`mp4scan`].
//! - [`decode`]: H.264 and AV1 samples back to YUV and RGB pixels.
//!
//! Nothing here knows a dataset, a folder layout or a format: the dataset layer
//! (`crate::export`) calls these and turns a [`MediaError`] into its own error, whose text and
//! exit code it keeps.

pub mod decode;
pub mod demux;
pub mod image;
pub(crate) mod mp4scan;
pub mod png_rows;

pub use mp4scan::in_quiet_parse;
pub mod tiff;
pub mod video;

use crate::error::{ErrorKind, HasKind};
use std::path::PathBuf;

/// What went wrong encoding, decoding or reading media, naming the file or stream.
#[derive(Debug, thiserror::Error)]
pub enum MediaError {
    /// Reading or writing a file failed.
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("encoding {what}")]
    Encode {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A stream that does not decode (damaged, or not what its container says).
    #[error("decoding {what}")]
    Decode {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A file that is not what its format requires.
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    /// Media surgvla has no codec for (another codec, profile or layout): not a defect of the
    /// data, the user's choice of input (exit 2).
    #[error("{0}")]
    Unsupported(String),
    /// Pixels that cannot be an image of the asked layout (a caller's episode).
    #[error("invalid episode: {0}")]
    BadPixels(String),
}

impl MediaError {
    pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> MediaError {
        let path = path.into();
        move |source| MediaError::Io { path, source }
    }
}

impl HasKind for MediaError {
    fn kind(&self) -> ErrorKind {
        match self {
            MediaError::Unsupported(_) => ErrorKind::Usage,
            _ => ErrorKind::Failed,
        }
    }

    fn is_disk_full(&self) -> bool {
        matches!(self, MediaError::Io { source, .. } if source.kind() == std::io::ErrorKind::StorageFull)
    }
}
