//! The one shape of a dataset format: [`DatasetFormat`], implemented once per format folder
//! (`lerobot/`, `rlds/`, `zarr/`, `mcap/`, `pointcloud/`) and listed once in
//! [`crate::export::registry::BUILTIN_FORMATS`], which `validate`, `info`, `convert`, `merge`,
//! [`crate::export::open_source`] and [`crate::export::open_sink`] all walk.
//!
//! A format recognises a path itself ([`DatasetFormat::sniff`]: no, yes, or "looks like me but
//! broken"), checks it into [`Findings`], and opens a sink, a source and a merge where it has
//! them. This module imports no format: formats import it.

use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, EpisodeSource, ExportError, SinkOptions, SourceOptions, Summary};
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
            let file = std::fs::File::open(path).map_err(unreadable)?;
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

/// A dataset a format recognised: which layout, and the folder (or file) to read.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    pub format: Format,
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

/// One dataset format: recognising, checking, writing, reading and merging its datasets.
pub trait DatasetFormat: Sync {
    /// The format's name, as `--to` says it.
    fn name(&self) -> &'static str;

    /// Whether `probe` is a dataset of this format.
    fn sniff(&self, probe: &Probe) -> Sniff;

    /// Checks a dataset [`DatasetFormat::sniff`] found, every defect a finding; returns the
    /// episodes and frames it holds.
    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> (u64, u64);

    /// Whether `options` are this format's.
    fn writes(&self, options: &SinkOptions) -> bool;

    /// Whether the format stores features as video (without decoding them) and features
    /// surgvla has no role for (`FeatureKind::Other`).
    fn holds(&self) -> Holds {
        Holds::default()
    }

    /// Starts (or, `resuming`, continues) a dataset in `root` with this format's `options`.
    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        options: &SinkOptions,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError>;

    /// Reads a dataset [`DatasetFormat::sniff`] found, episode by episode; `None`: surgvla
    /// does not read this format.
    fn open_source(
        &self,
        _found: &Found,
        _options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        None
    }

    /// Merges datasets of this format into `out`; `None`: the format does not merge.
    fn merge(&self, _request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        None
    }
}

/// What a format stores besides surgvla's own features.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Holds {
    /// Features that arrive as video, copied without decoding.
    pub video: bool,
    /// Features surgvla has no role for (another robot's state, another camera).
    pub other_features: bool,
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
