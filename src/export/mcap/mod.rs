//! MCAP recordings for Foxglove, one file per episode ([`McapWriter`]):
//! ```text
//! episode_NNNNNN.mcap     zstd chunks, summary, message and chunk indexes, CRCs
//! episodes.jsonl          per episode: index, file, frames, task id, level, seed, success, instruction
//! surgvla_manifest.json   every file with size and CRC-32C
//! ```
//! Topics (docs/datasets.md, "MCAP recordings"): `/endoscope/rgb` (foxglove.CompressedImage, PNG),
//! `/endoscope/depth` (foxglove.RawImage, 32FC1 metres), `/endoscope/camera_info`
//! (foxglove.CameraCalibration), `/endoscope/points` (foxglove.PointCloud, with depth), `/tf`
//! (foxglove.FrameTransforms), `/robot/state` and `/robot/action` (JSON with a JSON schema),
//! `/episode/info` (JSON, once), `/scene` (foxglove.SceneUpdate with the meshes, once, when
//! recording from the simulator), and an `episode` Metadata record with the provenance. Every
//! message of a step has log time = publish time = [`T0_NS`] + step / fps: a fixed origin, never
//! the wall clock, so the same episode gives the same bytes. The Metadata record is written
//! before any channel (writing it later leaves an empty chunk), and zstd runs on one thread.

pub mod check;
mod format;
mod merge;
pub mod messages;
mod writer;

pub use format::McapFormat;
pub use writer::{
    CHECKPOINT_EPISODES, MANIFEST, McapFiles, McapOptions, McapWriter, T0_NS, record_episode,
};
