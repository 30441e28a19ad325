//! What a LeRobot dataset is written with: [`LeRobotOptions`] (layout version, video mode,
//! data file size, PNG level) and [`VideoOptions`].

use crate::export::dir::RunOptions;
use crate::media::image::PngLevel;
use crate::media::video::Codec;
use serde::Serialize;

/// The codebase version written to info.json.
pub const CODEBASE_VERSION: &str = "v3.0";

/// Options of the LeRobot format (what the dataset holds is its [`crate::export::DatasetInfo`]).
#[derive(Clone, Debug, PartialEq)]
pub struct LeRobotOptions {
    /// A new data file starts once the current one reaches this size.
    pub data_file_size_mb: u64,
    /// Files per chunk folder.
    pub chunks_size: u64,
    pub png: PngLevel,
    /// Store the RGB camera as MP4 (video mode) instead of PNG in the parquet.
    pub video: Option<VideoOptions>,
    /// The on-disk layout.
    pub version: LeRobotVersion,
}

impl LeRobotOptions {
    /// What these options change in the bytes, by option name (for resume).
    pub fn run_options(&self) -> RunOptions {
        RunOptions::recorded(&Recorded {
            format: "lerobot",
            lerobot_version: match self.version {
                LeRobotVersion::V30 => "3.0",
                LeRobotVersion::V21 => "2.1",
            },
            video: self.video.map(|v| RecordedVideo {
                codec: v.codec.name(),
                quality: v.quality,
                file_mb: v.file_size_mb,
            }),
            data_file_mb: self.data_file_size_mb,
            chunks_size: self.chunks_size,
            png: self.png,
        })
    }
}

/// The options a LeRobot dataset records (see [`LeRobotOptions::run_options`]).
#[derive(Serialize)]
struct Recorded {
    format: &'static str,
    lerobot_version: &'static str,
    /// Null in image mode.
    video: Option<RecordedVideo>,
    data_file_mb: u64,
    chunks_size: u64,
    png: PngLevel,
}

/// The video options a LeRobot dataset records.
#[derive(Serialize)]
struct RecordedVideo {
    codec: &'static str,
    quality: u32,
    file_mb: u64,
}

impl Default for LeRobotOptions {
    fn default() -> Self {
        LeRobotOptions {
            data_file_size_mb: 100,
            chunks_size: 1000,
            png: PngLevel::Fast,
            video: None,
            version: LeRobotVersion::V30,
        }
    }
}

/// The LeRobot layout to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LeRobotVersion {
    /// v3.0: many episodes per data and video file, parquet metadata (lerobot >= 0.4).
    #[default]
    V30,
    /// v2.1: one parquet (and MP4) per episode, JSON-lines metadata (older consumers).
    V21,
}

/// Video mode settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VideoOptions {
    pub codec: Codec,
    /// Quality: H.264's largest quantiser (0 best .. 51), AV1's quantizer (0 best .. 255).
    pub quality: u32,
    /// A new video file starts once the current one reaches this size.
    pub file_size_mb: u64,
}

impl VideoOptions {
    /// H.264 at a high-quality quantiser range (the fast mode).
    pub fn h264() -> Self {
        VideoOptions {
            codec: Codec::H264,
            quality: Codec::H264.default_quality(),
            file_size_mb: 200,
        }
    }
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions {
            codec: Codec::Av1,
            quality: Codec::Av1.default_quality(),
            file_size_mb: 200,
        }
    }
}
