//! The built-in formats, one list ([`BUILTIN_FORMATS`]), and the walks every command makes over
//! it: which format a path holds ([`detect`]), a format by its name ([`by_name`]), the formats
//! that can do something ([`titles`] for messages), and merging ([`merge`]). Adding a format is
//! one folder implementing [`crate::export::format::DatasetFormat`] and [`crate::export::format::SinkOptions`] plus one
//! line here (and its flags in the command line: ARCHITECTURE.md's "How to add a format").

use crate::export::convert::ConvertError;
use crate::export::error::ExportError;
use crate::export::format::{Capabilities, Format, Found, MergeError, MergeRequest, Probe, Sniff};
use crate::export::sink::Summary;
use crate::export::{lerobot, mcap, pointcloud, rlds, zarr};
use std::path::Path;

/// Every format, in the order `--to` lists them. [`detect`] asks those
/// [`crate::export::DatasetFormat::sniffed_first`] first, then the rest in this order: the first that
/// recognises a path has it.
pub static BUILTIN_FORMATS: &[Format] = &[
    Format(&lerobot::LeRobotFormat),
    Format(&rlds::RldsFormat),
    Format(&pointcloud::PLY),
    Format(&pointcloud::PCD),
    Format(&zarr::ZarrFormat),
    Format(&mcap::McapFormat),
];

/// The format named `name` (as `--to` says it).
pub fn by_name(name: &str) -> Option<Format> {
    BUILTIN_FORMATS.iter().copied().find(|f| f.name() == name)
}

/// The format whose datasets come in `layout` (as a report names it: "lerobot-v2.1").
pub fn of_layout(layout: &str) -> Option<Format> {
    BUILTIN_FORMATS
        .iter()
        .copied()
        .find(|f| f.layouts().contains(&layout))
}

/// The titles of the formats whose capabilities pass `which`, as a list in a sentence:
/// "LeRobot and RLDS", "LeRobot, RLDS or zarr" (`last` joins the last two).
pub fn titles(which: impl Fn(&Capabilities) -> bool, last: &str) -> String {
    let names: Vec<&str> = BUILTIN_FORMATS
        .iter()
        .filter(|f| which(&f.capabilities()))
        .map(|f| f.title())
        .collect();
    match names.split_last() {
        None => String::new(),
        Some((only, [])) => (*only).to_string(),
        Some((final_one, rest)) => format!("{} {last} {final_one}", rest.join(", ")),
    }
}

/// What [`detect`] found: the format, its dataset, and, when it only looks like one, why it
/// cannot be read (`validate` still checks it, readers refuse it).
pub struct Detected {
    pub format: Format,
    pub found: Found,
    pub broken: Option<String>,
}

/// The format of the dataset at `path` and what it found there. A path that does not exist,
/// cannot be read or holds nothing a format recognises is an error (the user's: exit 2).
pub fn detect(path: &Path) -> Result<Detected, ExportError> {
    let probe = Probe::of(path)?;
    let first = BUILTIN_FORMATS.iter().filter(|f| f.sniffed_first());
    let then = BUILTIN_FORMATS.iter().filter(|f| !f.sniffed_first());
    for format in first.chain(then) {
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
    let several = BUILTIN_FORMATS.iter().find_map(|f| f.several(&probe));
    let problem = if probe.is_file {
        "is a file that is not MCAP; give a dataset folder or an .mcap file".to_string()
    } else if let Some(several) = several {
        several
    } else {
        format!(
            "holds nothing surgvla recognises ({} files)",
            titles(|_| true, "or")
        )
    };
    Err(ExportError::Unrecognised {
        path: path.to_path_buf(),
        problem,
    })
}

/// [`detect`] for a reader: a broken dataset is an error (the data's: exit 1).
pub fn detect_readable(path: &Path) -> Result<(Format, Found), ExportError> {
    let detected = detect(path)?;
    match detected.broken {
        None => Ok((detected.format, detected.found)),
        Some(problem) => Err(ExportError::InvalidDataset {
            path: detected.found.root,
            problem,
        }),
    }
}

/// Merges `request.inputs` (datasets of one format that merges) into `request.out`.
pub fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let first = request.inputs.first().ok_or(MergeError::NoInput)?.clone();
    let (format, found) = detect_readable(&first).map_err(read)?;
    for input in &request.inputs[1..] {
        let (other, _) = detect_readable(input).map_err(read)?;
        if other != format {
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
            format: found.layout,
            operation: "merge",
            handled: format!("{} datasets", titles(|c| c.merges, "and")),
        }))
    })
}
