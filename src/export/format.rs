//! The one shape of a dataset format: [`DatasetFormat`], implemented once per format folder
//! (`lerobot/`, `rlds/`, `zarr/`, `mcap/`, `pointcloud/`) and listed once in
//! [`crate::export::registry::BUILTIN_FORMATS`], which `validate`, `info`, `convert`, `merge`,
//! [`crate::export::open::open_source`] and [`crate::export::open::open_sink`] all walk.
//!
//! A format recognises a path itself ([`DatasetFormat::sniff`]: no, yes, or "looks like me but
//! broken"), checks it into [`Findings`], says what it can do ([`Capabilities`]), and opens a
//! source and a merge where it has them; its options ([`SinkOptions`]) open its sink. One value,
//! [`Format`], names a format anywhere. This module imports no format: formats import it.

use crate::export::error::ExportError;
use crate::export::findings::{Counts, Findings, ValidateOptions};
use crate::export::info::DatasetInfo;
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use crate::export::source::SourceOptions;
use std::path::{Path, PathBuf};

/// What [`DatasetFormat::sniff`] looks at: a path, read once for every format.
#[derive(Clone, Debug)]
pub struct Probe {
    pub path: PathBuf,
    /// A file rather than a folder.
    pub is_file: bool,
    /// A file's first eight bytes (fewer for a shorter file).
    pub magic: Vec<u8>,
    /// A folder's entry names.
    pub entries: Vec<String>,
}

impl Probe {
    /// Reads what the formats look at; a path that does not exist or cannot be read is an
    /// error naming it.
    pub fn of(path: &Path) -> Result<Probe, ExportError> {
        let metadata = std::fs::metadata(path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                ExportError::NotFound {
                    path: path.to_path_buf(),
                }
            } else {
                ExportError::Unreadable {
                    path: path.to_path_buf(),
                    source,
                }
            }
        })?;
        let unreadable = |source| ExportError::Unreadable {
            path: path.to_path_buf(),
            source,
        };
        if metadata.is_file() {
            let mut magic = Vec::with_capacity(8);
            let file = crate::files::open_regular(path).map_err(unreadable)?;
            std::io::Read::read_to_end(&mut std::io::Read::take(file, 8), &mut magic)
                .map_err(unreadable)?;
            return Ok(Probe {
                path: path.to_path_buf(),
                is_file: true,
                magic,
                entries: Vec::new(),
            });
        }
        let entries = std::fs::read_dir(path)
            .map_err(unreadable)?
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        Ok(Probe {
            path: path.to_path_buf(),
            is_file: false,
            magic: Vec::new(),
            entries,
        })
    }

    /// Whether the folder holds an entry of this name.
    pub fn has(&self, name: &str) -> bool {
        self.entries.iter().any(|e| e == name)
    }
}

/// A dataset a format recognised: its layout and the folder (or file) to read.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    /// The layout as reports name it: one of the format's [`DatasetFormat::layouts`]
    /// ("lerobot-v3.0", "rlds", "ply", ...).
    pub layout: &'static str,
    /// The dataset's own root: an RLDS version folder when given the data directory above it.
    pub root: PathBuf,
}

/// What a format says of a path.
#[derive(Clone, Debug, PartialEq)]
pub enum Sniff {
    /// Not this format.
    No,
    /// This format's dataset.
    Yes(Found),
    /// Looks like this format but cannot be read as a dataset (`problem` says why):
    /// `validate` still checks it (its defects are findings), readers refuse it.
    Broken { found: Found, problem: String },
}

/// What a format does: the registry, the command line and the dispatchers ask these instead of
/// naming formats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Capabilities {
    /// surgvla reads its datasets back as episodes ([`DatasetFormat::open_source`]).
    pub reads: bool,
    /// Its datasets merge ([`DatasetFormat::merge`]).
    pub merges: bool,
    /// It stores features that arrive as video without decoding them.
    pub video: bool,
    /// Which features surgvla has no role for (another robot's state, another camera) it
    /// stores.
    pub other_features: crate::export::roles::Others,
    /// It is built around one RGB camera, which another tool's dataset names with `--camera`
    /// ([`crate::export::roles::Roles`]).
    pub needs_camera: bool,
    /// It stores point clouds of the frames (whose points carry the mask ids, so collecting
    /// into it renders the mask).
    pub point_clouds: bool,
}

/// One dataset format: recognising, checking, writing, reading and merging its datasets.
pub trait DatasetFormat: Sync {
    /// The format's name, as `--to` says it.
    fn name(&self) -> &'static str;

    /// The format's name in a sentence ("LeRobot", "RLDS", "PLY").
    fn title(&self) -> &'static str;

    /// One line on the format for `--to`'s help.
    fn help(&self) -> &'static str;

    /// The layouts its datasets come in, as reports name them (the first is what it writes by
    /// default).
    fn layouts(&self) -> &'static [&'static str];

    /// What it does besides recognising, checking and writing.
    fn capabilities(&self) -> Capabilities;

    /// Whether a path must be offered to this format before the others, because its datasets
    /// also look like another format's (a zarr store has `meta/` and `data/`, as LeRobot has).
    fn sniffed_first(&self) -> bool {
        false
    }

    /// Whether `probe` is a dataset of this format.
    fn sniff(&self, probe: &Probe) -> Sniff;

    /// When no format recognises `probe`: why it is not one dataset of this format though it
    /// holds them (a TFDS data directory of several datasets names them), for the error.
    fn several(&self, _probe: &Probe) -> Option<String> {
        None
    }

    /// Checks a dataset [`DatasetFormat::sniff`] found, every defect a finding; returns the
    /// episodes and frames it holds.
    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> Counts;

    /// The folder holding the dataset's card (README.md): the found folder itself, or none for
    /// a single file.
    fn card_folder<'a>(&self, found: &'a Found) -> Option<&'a Path> {
        (!found.root.is_file()).then_some(found.root.as_path())
    }

    /// Reads a dataset [`DatasetFormat::sniff`] found, episode by episode; `None`: surgvla
    /// does not read this format ([`Capabilities::reads`] says which).
    fn open_source(
        &self,
        _found: &Found,
        _options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        None
    }

    /// The options that write a dataset like the one `found` is (of `info`, as its source
    /// read it): its layout, its video codec, its file sizes, its name. What `edit` writes
    /// its result with, so that the result is the input with episodes or features left out;
    /// `None`: the format cannot say (edit refuses it).
    fn options_like(
        &self,
        _found: &Found,
        _info: &DatasetInfo,
    ) -> Option<Result<Box<dyn SinkOptions>, ExportError>> {
        None
    }

    /// The files of a dataset `found` that another tool wrote beside the data and this
    /// format's writer does not make (a community's README, its own metadata), as (path
    /// relative to the dataset's root, bytes): `edit` carries them into its result as they
    /// are. None by default.
    fn carried_files(&self, _found: &Found) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        Ok(Vec::new())
    }

    /// Whether one dataset records several named splits of its episodes (LeRobot's
    /// `splits`); else a split is a dataset of its own (RLDS: its one TFDS split).
    fn records_splits(&self) -> bool {
        false
    }

    /// Merges datasets of this format into `out`; `None`: the format does not merge.
    fn merge(&self, _request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        None
    }

    /// What its features schema is, for `surgvla schema --format`'s help; `None`: it has none.
    fn schema_help(&self) -> Option<&'static str> {
        None
    }

    /// The features schema of a dataset of `info` in this format (what `surgvla schema`
    /// prints); `None` where [`DatasetFormat::schema_help`] is.
    fn schema(&self, _info: &DatasetInfo) -> Option<serde_json::Value> {
        None
    }
}

/// A format of the registry: the one value that names a format anywhere (compared by name).
#[derive(Clone, Copy)]
pub struct Format(pub &'static dyn DatasetFormat);

impl Format {
    /// The format's name, as `--to` says it.
    pub fn name(self) -> &'static str {
        self.0.name()
    }
}

impl std::ops::Deref for Format {
    type Target = dyn DatasetFormat;

    fn deref(&self) -> &Self::Target {
        self.0
    }
}

impl PartialEq for Format {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Format {}

impl std::fmt::Debug for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A format's own options for writing. Each format's options type implements it and opens its
/// sink with itself, so nothing casts options back to a format's.
pub trait SinkOptions: std::fmt::Debug + Send + Sync {
    /// The format these options write.
    fn format(&self) -> Format;

    /// Refuses values the format cannot write (a name its readers would refuse): the user's
    /// error.
    fn check(&self) -> Result<(), ExportError> {
        Ok(())
    }

    /// Whether a video feature of `info` must be decoded (and encoded again) although the
    /// format stores video: another codec asked for.
    fn reencodes(&self, _info: &DatasetInfo) -> bool {
        false
    }

    /// Starts (or, `resuming`, continues) a dataset of `info` in `root` with these options.
    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError>;
}

/// A merge: its inputs (in the order given), the output folder, worker threads (0: one per
/// core) and progress (episodes written so far).
pub struct MergeRequest<'a> {
    pub inputs: &'a [PathBuf],
    pub out: &'a Path,
    pub threads: usize,
    /// Continue the interrupted merge in `out` (the same inputs, checked by their identity).
    pub resume: bool,
    /// Recompute the pixel statistics of video features that carry no surgvla accumulator
    /// from every decoded frame (default: lerobot's combination of per-episode summaries by
    /// count).
    pub exact_stats: bool,
    pub progress: &'a mut (dyn FnMut(u64) + Send),
}

/// Why a merge could not start or failed.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// Inputs that cannot make one dataset.
    #[error("{path} cannot be merged with {first}: {reasons}")]
    Incompatible {
        path: PathBuf,
        first: PathBuf,
        reasons: String,
    },
    /// An input of a kind merge does not handle.
    #[error("{path}: {problem}")]
    Unsupported { path: PathBuf, problem: String },
    #[error("give at least one input dataset")]
    NoInput,
    /// Reading an input or writing the output failed.
    #[error(transparent)]
    Convert(#[from] crate::export::convert::ConvertError),
}

impl crate::error::HasKind for MergeError {
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            MergeError::Incompatible { .. }
            | MergeError::Unsupported { .. }
            | MergeError::NoInput => crate::error::ErrorKind::Usage,
            MergeError::Convert(error) => error.kind(),
        }
    }

    fn is_disk_full(&self) -> bool {
        matches!(self, MergeError::Convert(error) if error.is_disk_full())
    }
}
