//! The dataset layer's error: [`ExportError`], naming the file where there is one, and what it
//! is made of. Every module of the layer returns it; it imports none of them.

use crate::error::ErrorKind;
use crate::export::paths;
use serde_json::Value;
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
    /// A dataset of a format surgvla recognises (and validates) but does not read; `readers`
    /// names the formats it reads.
    #[error("{path}: surgvla does not read {format} datasets (it reads {readers})")]
    NotReadable {
        path: PathBuf,
        format: &'static str,
        readers: String,
    },
    /// A dataset of a format the operation does not handle.
    #[error("{path}: {operation} does not handle {format} datasets (it handles {handled})")]
    NotHandled {
        path: PathBuf,
        format: &'static str,
        operation: &'static str,
        handled: String,
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
        changes: Vec<OptionChange>,
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
    /// An input another layer reads (a recording) could not be read; its error names the file.
    #[error(transparent)]
    Input(Box<dyn std::error::Error + Send + Sync + 'static>),
    #[error("internal error: {0}")]
    Internal(String),
    /// The worker threads could not be started.
    #[error(transparent)]
    Threads(#[from] crate::threads::NoThreads),
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

/// A codec's error keeps its text and its kind: each becomes the dataset error it always was.
impl From<crate::media::MediaError> for ExportError {
    fn from(error: crate::media::MediaError) -> Self {
        use crate::media::MediaError;
        match error {
            MediaError::Io { path, source } => ExportError::Io { path, source },
            MediaError::Encode { what, source } => ExportError::Encode { what, source },
            MediaError::Decode { what, source } => ExportError::Decode { what, source },
            MediaError::Invalid { path, problem } => ExportError::InvalidDataset { path, problem },
            MediaError::Unsupported(message) => ExportError::InvalidOptions(message),
            MediaError::BadPixels(message) => ExportError::InvalidEpisode(message),
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

/// One option whose value differs between the recorded run and a resume.
#[derive(Clone, Debug, PartialEq)]
pub struct OptionChange {
    pub option: String,
    /// `None`: the option was not recorded (or is not given now).
    pub recorded: Option<Value>,
    pub given: Option<Value>,
}

impl std::fmt::Display for OptionChange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let show = |v: &Option<Value>| v.as_ref().map_or("(none)".into(), Value::to_string);
        if let (Some(Value::Array(was)), Some(Value::Array(now))) = (&self.recorded, &self.given) {
            let list = |items: Vec<&Value>| {
                items
                    .iter()
                    .map(|v| v.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let added: Vec<&Value> = now.iter().filter(|v| !was.contains(v)).collect();
            let removed: Vec<&Value> = was.iter().filter(|v| !now.contains(v)).collect();
            if !added.is_empty() || !removed.is_empty() {
                let mut parts = Vec::new();
                if !added.is_empty() {
                    parts.push(format!("now also {}", list(added)));
                }
                if !removed.is_empty() {
                    parts.push(format!("no longer {}", list(removed)));
                }
                return write!(f, "{}: {}", self.option, parts.join(", "));
            }
        }
        write!(
            f,
            "{} was {}, now {}",
            self.option,
            show(&self.recorded),
            show(&self.given)
        )
    }
}
