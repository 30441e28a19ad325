//! The built-in formats, one list ([`BUILTIN_FORMATS`]), and the walks every command makes over
//! it: which format a path holds ([`detect`]), which format writes a [`SinkOptions`]
//! ([`writer_of`]), and merging ([`merge`]). Adding a format is one folder implementing
//! [`DatasetFormat`] plus one line here (and its `SinkOptions` variant, its report name and
//! its `--to` value: ARCHITECTURE.md's "How to add a format").

use crate::export::format::{DatasetFormat, Found, MergeError, MergeRequest, Probe, Sniff};
use crate::export::{ExportError, SinkOptions, Summary, lerobot, mcap, pointcloud, rlds, zarr};
use std::path::Path;

/// Every format, in the order [`detect`] asks them (the first that recognises a path has it).
pub static BUILTIN_FORMATS: &[&dyn DatasetFormat] = &[
    &zarr::ZarrFormat,
    &lerobot::LeRobotFormat,
    &rlds::RldsFormat,
    &mcap::McapFormat,
    &pointcloud::CloudFilesFormat,
];

/// What [`detect`] found: the format, its dataset, and, when it only looks like one, why it
/// cannot be read (`validate` still checks it, readers refuse it).
pub struct Detected {
    pub format: &'static dyn DatasetFormat,
    pub found: Found,
    pub broken: Option<String>,
}

/// The format of the dataset at `path` and what it found there. A path that does not exist,
/// cannot be read or holds nothing a format recognises is an error (the user's: exit 2).
pub fn detect(path: &Path) -> Result<Detected, ExportError> {
    let probe = Probe::of(path)?;
    for format in BUILTIN_FORMATS {
        let (found, broken) = match format.sniff(&probe) {
            Sniff::No => continue,
            Sniff::Yes(found) => (found, None),
            Sniff::Broken { found, problem } => (found, Some(problem)),
        };
        return Ok(Detected {
            format: *format,
            found,
            broken,
        });
    }
    let problem = if probe.is_file {
        "is a file that is not MCAP; give a dataset folder or an .mcap file"
    } else {
        "holds nothing surgvla recognises (LeRobot, RLDS, zarr, MCAP or point-cloud files)"
    };
    Err(ExportError::Unrecognised {
        path: path.to_path_buf(),
        problem: problem.into(),
    })
}

/// [`detect`] for a reader: a broken dataset is an error (the data's: exit 1).
pub fn detect_readable(path: &Path) -> Result<(&'static dyn DatasetFormat, Found), ExportError> {
    let detected = detect(path)?;
    match detected.broken {
        None => Ok((detected.format, detected.found)),
        Some(problem) => Err(ExportError::InvalidDataset {
            path: detected.found.root,
            problem,
        }),
    }
}

/// The format whose options these are.
pub fn writer_of(options: &SinkOptions) -> Result<&'static dyn DatasetFormat, ExportError> {
    BUILTIN_FORMATS
        .iter()
        .find(|f| f.writes(options))
        .copied()
        .ok_or_else(|| ExportError::Internal(format!("no format writes {options:?}")))
}

/// Merges `request.inputs` (datasets of one format that merges) into `request.out`.
pub fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(crate::export::convert::ConvertError::Read(e));
    let first = request.inputs.first().ok_or(MergeError::NoInput)?.clone();
    let (format, found) = detect_readable(&first).map_err(read)?;
    for input in &request.inputs[1..] {
        let (other, _) = detect_readable(input).map_err(read)?;
        if other.name() != format.name() {
            return Err(MergeError::Incompatible {
                path: input.clone(),
                first,
                reasons: format!("it is {}, the first is {}", other.name(), format.name()),
            });
        }
    }
    format.merge(request).unwrap_or_else(|| {
        Err(read(ExportError::NotHandled {
            path: first,
            format: found.format.name(),
            operation: "merge",
            handled: "LeRobot, RLDS, zarr, PLY/PCD and MCAP datasets",
        }))
    })
}
