//! The LeRobot format: v3.0 (default) and v2.1, written by [`LeRobotWriter`], read by
//! [`read::LeRobotSource`].
//!
//! Layout (what `lerobot.datasets.LeRobotDataset` 0.6 reads; v2.1 differences in [`layout`]):
//! ```text
//! meta/info.json                          written last: its presence marks a complete dataset
//! meta/stats.json                         min, max, mean, std, count, q01..q99 per feature
//! meta/tasks.parquet                      task_index, task (pandas-indexed by task)
//! meta/episodes/chunk-000/file-000.parquet  rows, per-episode stats, surgvla/ provenance
//! meta/surgvla.json                       camera intrinsics and pose, mask ids, collection
//! data/chunk-CCC/file-FFF.parquet         frames; one row group per episode, rolled by size
//! videos/KEY/chunk-CCC/file-FFF.mp4       video mode: the RGB camera, episodes concatenated
//! ```
//! Images are embedded: RGB and mask as PNG, depth as float32 TIFF in metres
//! (`is_depth_map`, `depth_unit: "m"`). The folder, its marker, temporary names and checkpoints
//! belong to [`crate::export::DatasetDir`]; whenever a data file closes (and the open MP4 with it) the writer's
//! whole state is checkpointed, and [`LeRobotWriter::resume`] continues from there.

mod carry;
pub mod check;
mod copy;
mod format;
mod layout;
pub mod merge;
pub mod meta;
pub mod openh;
mod options;
mod parts;
pub mod read;
mod rows;
mod table;
pub mod work;
mod writer;

pub use crate::media::video::Codec;
pub use format::LeRobotFormat;
pub use meta::{FeatureJson, InfoJson};
pub use options::{CODEBASE_VERSION, LeRobotOptions, LeRobotVersion, VideoOptions};
pub use table::{DEFAULT_COLUMNS, Provenance, fixed_size_lists, frame_schema, image_fields};
pub use writer::{LeRobotFiles, LeRobotWriter, State, features_json};
