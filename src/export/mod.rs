//! The dataset layer: every format's sink and source.
//!
//! Every format has one shape. A [`DatasetInfo`] states the dataset once (features, fps,
//! camera, robot, collection); [`open_sink`] creates (or resumes) a format's [`EpisodeSink`] on
//! it in a folder owned by [`DatasetDir`] (marker, temporary names, checkpoints); the sink takes
//! consecutive [`Episode`]s in batches ([`EpisodeSink::write_batch`]) and
//! [`EpisodeSink::finish`] completes the dataset and returns a [`Summary`] (calling it again
//! returns the same summary). Readers are [`EpisodeSource`]s of the same [`Episode`] type.
//! Formats share image encoding ([`image`], [`tiff`]), video ([`video`]) and statistics
//! ([`stats`]). Formats never depend on the simulator: they see episodes only.
//!
//! Adding a format means one folder implementing [`EpisodeSink`] (and [`EpisodeSource`] where it
//! reads) plus its variant of [`SinkOptions`].
//!
//! - [`lerobot`]: LeRobot v3.0 and v2.1 (parquet + metadata, images embedded or MP4 video).
//! - [`rlds`]: RLDS in the TFDS layout (TFRecord shards of `tf.train.Example` episodes).
//! - [`pointcloud`]: point clouds of frames; one PLY or PCD file per frame.
//! - [`zarr`]: the DP3 zarr v2 store (point clouds, state, action, optional images).
//! - [`mcap`]: one MCAP recording per episode, Foxglove's well-known schemas.
//!
//! [`convert`] copies any source into any sink.

pub mod bounded;
pub mod card;
pub mod convert;
pub mod decode;
pub mod demux;
pub mod dir;
pub mod findings;
pub mod format;
pub mod identity;
pub mod image;
pub mod info;
pub mod lerobot;
pub mod mcap;
pub mod merge;
pub(crate) mod mp4scan;
pub mod paths;
pub mod pointcloud;
pub mod profile;
pub mod registry;
pub mod rlds;
pub mod schema;
pub mod shard;
pub mod stats;
pub mod tiff;
pub mod validate;
pub mod verify;
pub mod video;
pub(crate) mod writer;
pub mod zarr;

pub use dir::{
    DatasetDir, FileRecord, INCOMPLETE_MARKER, MANIFEST, OptionChange, RunOptions, temporary_name,
    write_atomically,
};
pub use format::{DatasetFormat, MergeError};
pub use info::DatasetInfo;
pub use registry::{BUILTIN_FORMATS, merge};

use crate::episode::{Episode, Pixels, Step};
use crate::error::ErrorKind;
use std::path::{Path, PathBuf};

/// What went wrong while writing or reading a dataset, naming the file where there is one.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The output folder could not be made or used (a file in the way, no permission).
    #[error("cannot write the dataset to {path}")]
    Output {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}")]
    Parquet {
        path: PathBuf,
        #[source]
        source: parquet::errors::ParquetError,
    },
    #[error("{path}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("building arrow data")]
    Arrow(#[from] arrow_schema::ArrowError),
    /// An input path that does not exist.
    #[error("{path} does not exist")]
    NotFound { path: PathBuf },
    /// An input path that cannot be read (permissions).
    #[error("cannot read {path}")]
    Unreadable {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// An input path that holds nothing surgvla recognises.
    #[error("{path} {problem}")]
    Unrecognised { path: PathBuf, problem: String },
    /// A dataset of a format surgvla recognises (and validates) but does not read.
    #[error("{path}: surgvla does not read {format} datasets (it reads LeRobot and RLDS)")]
    NotReadable { path: PathBuf, format: &'static str },
    /// A dataset of a format the operation does not handle.
    #[error("{path}: {operation} does not handle {format} datasets (it handles {handled})")]
    NotHandled {
        path: PathBuf,
        format: &'static str,
        operation: &'static str,
        handled: &'static str,
    },
    /// Point clouds of a dataset that records no workspace to crop them to.
    #[error("the dataset does not record the robot's workspace, so the clouds need a crop box")]
    NoCropBox,
    /// An RLDS dataset another tool wrote: RLDS stores no frame rate, so the reader needs one.
    #[error("{path} is an RLDS dataset another tool wrote, and RLDS stores no frame rate")]
    NoFrameRate { path: PathBuf },
    #[error("{}", not_empty(path, *interrupted))]
    NotEmpty { path: PathBuf, interrupted: bool },
    /// Another run holds the folder's lock.
    #[error(
        "{path} is being written by another run ({holder}); wait for it to end or choose another directory"
    )]
    Locked { path: PathBuf, holder: String },
    /// A resume with options that change the dataset's bytes.
    #[error(
        "cannot resume {path} with other options than the run that started it ({}); give the same options, or start a new dataset in another directory",
        changes.iter().map(ToString::to_string).collect::<Vec<_>>().join("; ")
    )]
    OptionsChanged {
        path: PathBuf,
        changes: Vec<dir::OptionChange>,
    },
    /// A file an interrupted dataset's checkpoint lists is missing or changed.
    #[error(
        "{path} {problem}: the interrupted dataset cannot be resumed safely; delete its folder and run again"
    )]
    Damaged { path: PathBuf, problem: String },
    #[error("cannot resume {path}: {reason}")]
    NotResumable { path: PathBuf, reason: String },
    #[error("invalid episode: {0}")]
    InvalidEpisode(String),
    /// A format's options that cannot make a loadable dataset (a name or key the readers
    /// refuse).
    #[error("{0}")]
    InvalidOptions(String),
    /// A name or template in a dataset's metadata (or a file name made from one) that cannot
    /// be a path inside the dataset ([`paths`]).
    #[error("{path}: the {what} {name:?} cannot be a path inside the dataset")]
    UnsafeName {
        path: PathBuf,
        what: &'static str,
        name: String,
        #[source]
        problem: paths::UnsafeName,
    },
    /// A dataset being read is not what its format requires.
    #[error("{path}: {problem}")]
    InvalidDataset { path: PathBuf, problem: String },
    #[error("encoding {what}")]
    Encode {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A video stream that does not decode (damaged, or not what its container says).
    #[error("decoding {what}")]
    Decode {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("internal error: {0}")]
    Internal(String),
}

impl ExportError {
    pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> ExportError {
        let path = path.into();
        move |source| ExportError::Io { path, source }
    }

    /// A parquet error naming `path`; an I/O failure inside it (a full disk) stays an I/O error.
    pub(crate) fn parquet(
        path: &Path,
    ) -> impl Fn(parquet::errors::ParquetError) -> ExportError + use<> {
        let path = path.to_path_buf();
        move |source| match source {
            parquet::errors::ParquetError::External(inner) => {
                match inner.downcast::<std::io::Error>() {
                    Ok(io) => ExportError::Io {
                        path: path.clone(),
                        source: *io,
                    },
                    Err(other) => ExportError::Parquet {
                        path: path.clone(),
                        source: parquet::errors::ParquetError::External(other),
                    },
                }
            }
            source => ExportError::Parquet {
                path: path.clone(),
                source,
            },
        }
    }
}

impl crate::error::HasKind for ExportError {
    /// Whether the disk (or quota) is full.
    fn is_disk_full(&self) -> bool {
        match self {
            ExportError::Io { source, .. } | ExportError::Output { source, .. } => {
                source.kind() == std::io::ErrorKind::StorageFull
            }
            _ => false,
        }
    }

    /// Whose mistake it is: the user's (a folder that cannot be used, a dataset that cannot be
    /// resumed) or the work's (I/O during writing, a full disk, invalid data).
    fn kind(&self) -> ErrorKind {
        match self {
            ExportError::Output { .. }
            | ExportError::NotEmpty { .. }
            | ExportError::Locked { .. }
            | ExportError::OptionsChanged { .. }
            | ExportError::InvalidOptions(_)
            | ExportError::NotFound { .. }
            | ExportError::Unreadable { .. }
            | ExportError::Unrecognised { .. }
            | ExportError::NotReadable { .. }
            | ExportError::NotHandled { .. }
            | ExportError::NoFrameRate { .. }
            | ExportError::NoCropBox
            | ExportError::NotResumable { .. } => ErrorKind::Usage,
            _ => ErrorKind::Failed,
        }
    }
}

/// Reads a JSON file, naming it in the error.
pub(crate) fn read_json(path: &Path) -> Result<serde_json::Value, ExportError> {
    let bytes = bounded::read_metadata(path)?;
    serde_json::from_slice(&bytes).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })
}

fn not_empty(path: &Path, interrupted: bool) -> String {
    if interrupted {
        format!("{} holds an interrupted surgvla dataset", path.display())
    } else {
        format!(
            "{} already holds a dataset or other files; choose an empty or new directory",
            path.display()
        )
    }
}

/// What a sink wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub episodes: u64,
    pub frames: u64,
    pub files: u64,
    pub bytes: u64,
}

/// Seconds a sink spent, for reports (never written into a dataset).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SinkTiming {
    /// Encoding images and video: thread-seconds when a detached encoder did it (summed over
    /// the threads), else wall seconds of the batches' parallel encoding (statistics included
    /// where the format does not count them apart).
    pub encode_secs: f64,
    /// Computing statistics (thread-seconds; 0 where the format does not count them apart).
    pub stats_secs: f64,
    /// Building tables and writing files.
    pub write_secs: f64,
}

/// An episode encoded for one sink by its detached encoder, ahead of its turn (what
/// [`EpisodeSink::write_encoded`] appends).
pub struct Encoded(pub(crate) Box<dyn std::any::Any + Send>);

/// Encodes episodes for a sink on any thread, apart from the sink (see
/// [`EpisodeSink::detached_encoder`]). It checks the sizes of the images it encodes, which
/// [`EpisodeSink::write_encoded`] then leaves out of its checks.
pub trait DetachedEncoder: Send + Sync {
    fn encode(&self, episode: &Episode) -> Result<Encoded, ExportError>;
    /// An encoder of one episode frame by frame while it is recorded, so that each frame is
    /// encoded while its pixels are in the core's cache and its buffers can be drawn into
    /// again; `None` when the sink needs whole episodes. `expected_frames` sizes its buffers.
    fn frames(&self, _expected_frames: usize) -> Option<Box<dyn FrameEncoder>> {
        None
    }
}

/// Encodes one episode frame by frame (see [`DetachedEncoder::frames`]): the same bytes as
/// [`DetachedEncoder::encode`] of the whole episode.
pub trait FrameEncoder: Send {
    /// Takes the next step's images (it is kept without them) to encode them and take its
    /// statistics, in small batches; returns the buffers of earlier steps it is done with.
    fn push(&mut self, step: &mut Step) -> Result<Vec<Pixels>, ExportError>;
    /// The episode whose steps were pushed, encoded (its steps' pixels may be gone).
    fn finish(self: Box<Self>, episode: &Episode) -> Result<Encoded, ExportError>;
}

/// Receives consecutive episodes, in episode-index order, and writes one dataset.
pub trait EpisodeSink {
    /// Writes consecutive episodes (a sink may work on them in parallel; the output is as if
    /// they were written one by one). An episode out of order or not matching the dataset's
    /// features is rejected.
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError>;
    /// Writes one episode.
    fn write_episode(&mut self, episode: &Episode) -> Result<(), ExportError> {
        self.write_batch(std::slice::from_ref(episode))
    }
    /// An encoder that works apart from the sink: a producer encodes each episode on its own
    /// threads as soon as it is made, and the sink's [`EpisodeSink::write_encoded`] only
    /// appends. `None`: the sink encodes inside [`EpisodeSink::write_batch`].
    fn detached_encoder(&self) -> Option<std::sync::Arc<dyn DetachedEncoder>> {
        None
    }
    /// Writes consecutive episodes with what this sink's detached encoder made of each (the
    /// same bytes as [`EpisodeSink::write_batch`] of the episodes).
    fn write_encoded(&mut self, _episodes: Vec<(Episode, Encoded)>) -> Result<(), ExportError> {
        Err(ExportError::Internal(
            "this sink has no detached encoder".into(),
        ))
    }
    /// Index of the next episode the sink expects (after a resume: the first one to rewrite).
    fn next_episode_index(&self) -> u64;
    /// Whether the sink copies a source's stored still images of `encoding` (PNG, TIFF, JPEG)
    /// instead of encoding the pixels again (see [`writer::FormatWriter::reuses_stored`]).
    fn reuses_stored(&self, _encoding: crate::episode::ImageEncoding) -> bool {
        true
    }
    /// Time spent so far.
    fn timing(&self) -> SinkTiming {
        SinkTiming::default()
    }
    /// Completes the dataset: after this returns Ok, it is consistent and loadable. Calling it
    /// again returns the same summary and writes nothing.
    fn finish(&mut self) -> Result<Summary, ExportError> {
        self.finish_with(None)
    }
    /// [`EpisodeSink::finish`], writing `sidecar`'s file (made from the summary; e.g. a run's
    /// report) into the folder after the dataset's own files and before the dataset is marked
    /// complete, so an interrupted finish leaves a resumable dataset, never one without it.
    /// Sidecar files are not in the manifest.
    fn finish_with(&mut self, sidecar: Option<Sidecar<'_>>) -> Result<Summary, ExportError>;
}

/// What every sink checks before it writes an episode: that the dataset is not finished yet,
/// that the episode is the `expected` one (episodes come in index order), and that its steps
/// hold the dataset's features.
pub(crate) fn check_episode(
    info: &DatasetInfo,
    finished: bool,
    episode: &Episode,
    expected: u64,
    pixels: bool,
) -> Result<(), ExportError> {
    if finished {
        return Err(ExportError::Internal(
            "an episode arrived after the dataset was finished".into(),
        ));
    }
    if episode.meta.index != expected {
        return Err(ExportError::InvalidEpisode(format!(
            "episode index {} arrived where {expected} was expected (episodes must come in order)",
            episode.meta.index
        )));
    }
    // Video that cannot be copied (the user's choice to copy it, not a defect): exit 2.
    if let Some(video) = episode.encoded.iter().find(|e| {
        e.shown.is_some()
            && info
                .features
                .iter()
                .any(|f| f.name == e.feature && !f.in_steps())
    }) {
        return Err(ExportError::InvalidOptions(format!(
            "episode {}: {}'s video is not one frame per row in presentation order (B-frames, or frames the rows skip), so it cannot be copied as it is: decode it (convert --decode, or --video to re-encode)",
            episode.meta.index, video.feature
        )));
    }
    episode
        .validate_structure(&info.features)
        .map_err(ExportError::InvalidEpisode)?;
    if pixels {
        let (width, height) = info.image_size();
        episode
            .validate_pixels(width, height, &info.features)
            .map_err(ExportError::InvalidEpisode)?;
    }
    Ok(())
}

/// [`check_episode`] for consecutive episodes starting at `first`.
pub(crate) fn check_batch(
    info: &DatasetInfo,
    finished: bool,
    episodes: &[Episode],
    first: u64,
    pixels: bool,
) -> Result<(), ExportError> {
    (first..)
        .zip(episodes)
        .try_for_each(|(index, episode)| check_episode(info, finished, episode, index, pixels))
}

/// Makes a file to write beside a finished dataset from its summary: (relative path, bytes).
pub type Sidecar<'a> = &'a mut dyn FnMut(&Summary) -> Result<(String, Vec<u8>), ExportError>;

/// Reads a dataset back: its [`DatasetInfo`] and its episodes in order, one at a time (memory
/// bounded by one episode).
pub trait EpisodeSource {
    fn info(&self) -> &DatasetInfo;
    /// Episodes in the dataset.
    fn len(&self) -> u64;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The next episode, or None after the last.
    fn next_episode(&mut self) -> Option<Result<Episode, ExportError>>;
    /// Leaves the stored still images (PNG, TIFF, JPEG) of the `unused` encodings out of the
    /// episodes' [`Episode::encoded`] from now on: a conversion whose target would encode them
    /// again says so before reading, so that no episode in flight holds its frames twice.
    /// Sources that keep none ignore it.
    fn drop_stored(&mut self, _unused: &[crate::episode::ImageEncoding]) {}
    /// Passes over the next episode (None after the last): what a shard does with the
    /// episodes before its range. Reading and dropping it by default; a source that can skip
    /// without decoding does so.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next_episode().map(|e| e.map(|_| ()))
    }
}

/// A format and its own options.
#[derive(Clone, Debug, PartialEq)]
pub enum SinkOptions {
    LeRobot(lerobot::LeRobotOptions),
    Rlds(rlds::RldsOptions),
    /// One point-cloud file per frame.
    CloudFiles(
        pointcloud::files::CloudFileFormat,
        pointcloud::CloudSettings,
    ),
    /// The DP3 zarr store.
    Zarr(zarr::ZarrOptions),
    /// One MCAP recording per episode.
    Mcap(mcap::McapOptions),
}

impl SinkOptions {
    /// What the format's options change in the bytes, by option name (for resume), with the
    /// format's name under `format`.
    pub fn run_options(&self) -> RunOptions {
        match self {
            SinkOptions::LeRobot(options) => options.run_options(),
            SinkOptions::Rlds(options) => options.run_options(),
            SinkOptions::CloudFiles(format, settings) => {
                let mut options = settings.run_options();
                options.set("format", serde_json::json!(format));
                options
            }
            SinkOptions::Zarr(options) => options.run_options(),
            SinkOptions::Mcap(options) => options.run_options(),
        }
    }
}

/// Whether a conversion of a dataset of `info` into `options` must decode its video (through
/// [`decode::Decoded`]): the format does not store video, or LeRobot is asked for another
/// codec than a video feature's.
pub fn decoding_needed(info: &DatasetInfo, options: &SinkOptions) -> Result<bool, ExportError> {
    if !decode::Decoded::needed(info) {
        return Ok(false);
    }
    if !registry::writer_of(options)?.holds().video {
        return Ok(true);
    }
    Ok(match options {
        SinkOptions::LeRobot(lerobot) => lerobot.video.is_some_and(|video| {
            info.features
                .iter()
                .any(|f| f.video.is_some_and(|codec| codec != video.codec))
        }),
        _ => false,
    })
}

/// Whether [`open_sink`] with `resume` continues the dataset in `root` (it holds an interrupted
/// one) rather than starting a new one.
pub fn resumes(root: &Path, resume: bool) -> bool {
    resume && DatasetDir::is_interrupted(root)
}

/// Starts a dataset of `info` in `root` (which must not exist or be empty), or, when
/// [`resumes`], continues it from its last checkpoint ([`EpisodeSink::next_episode_index`] says
/// where), in the format whose `options` these are.
pub fn open_sink(
    root: &Path,
    info: &DatasetInfo,
    options: &SinkOptions,
    resume: bool,
) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
    let format = registry::writer_of(options)?;
    let holds = format.holds();
    let videos: Vec<String> = info
        .features
        .iter()
        .filter_map(|f| Some(format!("{} ({})", f.name, f.video?.name())))
        .collect();
    if !videos.is_empty() && !holds.video {
        return Err(ExportError::InvalidOptions(format!(
            "the input stores {} as video, which this format needs decoded (read the input through decode::Decoded)",
            videos.join(", ")
        )));
    }
    let others: Vec<&str> = info
        .features
        .iter()
        .filter(|f| f.kind == crate::episode::FeatureKind::Other)
        .map(|f| f.name.as_str())
        .collect();
    if !others.is_empty() && !holds.other_features {
        return Err(ExportError::InvalidOptions(format!(
            "the features {} have no place in this format yet (point clouds, zarr and MCAP hold surgvla's features: an RGB camera, 7-D state and action, depth); convert to LeRobot or RLDS",
            others.join(", ")
        )));
    }
    format.open_sink(root, info, options, resumes(root, resume))
}

/// What a reader needs to know that a dataset may not say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceOptions {
    /// Steps per second, for datasets that store none (RLDS another tool wrote).
    pub fps: Option<u32>,
    /// The robot type of such datasets ("unknown" when not given).
    pub robot_type: Option<String>,
}

/// Opens a dataset for reading, detecting its format through the registry (LeRobot, or RLDS:
/// a TFDS version folder or the data directory above it). A path holding nothing recognised,
/// or a format surgvla does not read, is the user's error.
pub fn open_source(root: &Path) -> Result<Box<dyn EpisodeSource + Send>, ExportError> {
    open_source_with(root, &SourceOptions::default())
}

/// [`open_source`] with what the dataset may not say: an RLDS dataset surgvla did not write
/// (no `surgvla.json` beside its `dataset_info.json`) is read through its own `features.json`
/// and needs `options.fps`.
pub fn open_source_with(
    root: &Path,
    options: &SourceOptions,
) -> Result<Box<dyn EpisodeSource + Send>, ExportError> {
    let (format, found) = registry::detect_readable(root)?;
    let source = format.open_source(&found, options).unwrap_or_else(|| {
        Err(ExportError::NotReadable {
            path: found.root.clone(),
            format: found.format.name(),
        })
    })?;
    Ok(Box::new(identity::Identified::new(source, &found.root)?))
}
