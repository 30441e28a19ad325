//! surgvla: generate, convert and validate datasets for surgical robot learning.
//!
//! - [`sim`]: the headless simulator (dVRK PSM, rapier scene, grasp binding).
//! - [`task`]: the eight benchmark tasks and their seeded scenes.
//! - [`policy`]: policies, including the waypoint expert controller.
//! - [`env`]: the environment API (reset, step, observe) that collection and evaluation share.
//! - [`collect`]: verified expert collection into any dataset sink.
//! - [`export`]: the dataset layer: `DatasetInfo`, every format's sink and source.
//! - [`ingest`]: robot recordings in: ROS message definitions, ROS 1 and CDR decoding, ROS 1
//!   bags.
//! - [`media`]: image and video codecs (PNG, JPEG, TIFF, AV1, H.264, MP4), below any dataset.
//! - [`chart`]: charts as PNG in pure Rust (success rates, dataset histograms).
//! - [`error`]: the kinds of failure (user's input or the work), for exit codes.
//!
//! The library never sees command-line types, progress bars or exit codes; `src/bin/surgvla.rs`
//! owns those. Every output is a pure function of (config, seed).

pub mod assets;
pub mod chart;
pub mod collect;
pub mod env;
pub mod episode;
pub mod error;
pub mod eval;
pub mod export;
pub mod files;
pub mod ingest;
pub mod media;
pub mod noise;
pub mod policy;
pub mod render;
pub mod rng;
pub mod scene;
pub mod sim;
pub mod task;
pub mod threads;
pub mod view;
