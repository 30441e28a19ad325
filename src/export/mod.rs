//! The dataset layer: every format's sink and source.
//!
//! Every format has one shape. A [`DatasetInfo`] states the dataset once (features, fps,
//! camera, robot, collection); [`open_sink`] creates (or resumes) a format's [`EpisodeSink`] on
//! it in a folder owned by [`DatasetDir`] (marker, temporary names, checkpoints); the sink takes
//! consecutive episodes in batches ([`EpisodeSink::write_batch`]) and [`EpisodeSink::finish`]
//! completes the dataset and returns a [`Summary`] (calling it again returns the same summary).
//! Readers are [`EpisodeSource`]s of the same episode type. Formats share statistics
//! ([`stats`]) and the media codecs of [`crate::media`]. Formats never depend on the simulator:
//! they see episodes only.
//!
//! This file only declares and re-exports. The layer has three floors, each importing only the
//! ones below it:
//! - what every format shares: [`error`], [`sink`], [`source`], [`format`] (the
//!   [`DatasetFormat`] and [`SinkOptions`] traits), [`info`], [`dir`], [`writer`],
//!   [`findings`], [`stats`], [`convert`] (any source into any sink), [`decoded`], ...;
//! - the formats, one folder each: [`lerobot`] (v3.0 and v2.1), [`rlds`] (TFDS), [`pointcloud`]
//!   (PLY and PCD files), [`zarr`] (DP3), [`mcap`] (Foxglove);
//! - the dispatch over them: [`registry`] (the one list of formats), [`open`], [`validate`],
//!   [`verify`], [`edit`].
//!
//! Adding a format is one folder implementing [`DatasetFormat`] and [`SinkOptions`] plus one
//! line in [`registry::BUILTIN_FORMATS`] (ARCHITECTURE.md's "How to add a format").

pub mod bounded;
pub mod card;
pub mod check;
pub mod collection;
pub mod conventions;
pub mod convert;
pub mod decoded;
pub mod dir;
pub mod edit;
pub mod error;
pub mod findings;
pub mod format;
pub mod identity;
pub mod info;
pub mod lerobot;
pub mod lint;
pub mod mcap;
pub mod merge;
pub mod open;
pub mod paths;
pub mod pipeline;
pub mod pointcloud;
pub mod profile;
pub mod registry;
pub mod rlds;
pub mod roles;
pub mod schema;
pub mod shard;
pub mod sink;
pub mod source;
pub mod stats;
pub mod validate;
pub mod verify;
pub(crate) mod writer;
pub mod zarr;

pub use dir::{
    DatasetDir, FileRecord, INCOMPLETE_MARKER, MANIFEST, RunOptions, resumes, temporary_name,
    write_atomically,
};
pub use error::{ExportError, OptionChange};
pub use format::{DatasetFormat, Format, MergeError, SinkOptions};
pub use info::DatasetInfo;
pub use open::{decoding_needed, open_sink, open_source, open_source_with};
pub use registry::{BUILTIN_FORMATS, merge};
pub use sink::{
    DetachedEncoder, Encoded, EpisodeSink, FrameEncoder, Pipelined, PipelinedSink, Sidecar,
    SinkTiming, Summary,
};
pub use source::{EpisodePart, EpisodeSource, Gathering, Skimmed, SourceOptions};
