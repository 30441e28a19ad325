//! Validating a folder of point-cloud files ([`super::files::CloudFilesWriter`]'s layout):
//! `surgvla.json` (our metadata, with the cloud settings and the file format), `episodes.jsonl`
//! (one line per episode), each episode's folder holding exactly the frames its line states,
//! every frame read as plyfile or PCL would read it ([`super::frame`]; `--quick`: its header
//! and length), with or without the manifest. Returns what the folder holds, counted from the files.

use super::files::CloudFileFormat;
use super::frame;
use crate::export::bounded::{open_regular, read_capped, read_json};
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::findings::{At, FeatureFact, Findings, ValidateOptions, check_manifest};
use crate::export::schema;
use std::io::Read;
use std::path::Path;

/// Checks the folder at `root` of `extension` files; returns (episodes, frames) on disk.
pub fn check(
    root: &Path,
    extension: &str,
    options: &ValidateOptions,
    findings: &Findings,
) -> (u64, u64) {
    let max_points = check_metadata(root, extension, findings);
    check_manifest(root, super::files::MANIFEST, options.quick, findings);
    let episodes = crate::export::bounded::read_metadata(&root.join(super::files::EPISODES));
    let stated = match episodes.map(|bytes| String::from_utf8_lossy(&bytes).into_owned()) {
        Ok(text) => text,
        Err(_) => {
            findings.error(
                At::file(super::files::EPISODES),
                Check::Present,
                "is missing",
            );
            String::new()
        }
    };
    let rule = FrameRule {
        format: match extension {
            "pcd" => CloudFileFormat::Pcd,
            _ => CloudFileFormat::Ply,
        },
        max_points,
        quick: options.quick,
    };
    let (mut episodes, mut frames) = (0u64, 0u64);
    for (line_number, line) in stated.lines().enumerate() {
        let at = || At::file(super::files::EPISODES);
        let Ok(line) = serde_json::from_str::<serde_json::Value>(line) else {
            findings.error(
                at(),
                Check::Schema,
                format!("line {} is not JSON", line_number + 1),
            );
            continue;
        };
        let (Some(index), Some(count)) = (line["episode_index"].as_u64(), line["frames"].as_u64())
        else {
            findings.error(
                at(),
                Check::Schema,
                format!("line {} lacks episode_index or frames", line_number + 1),
            );
            continue;
        };
        if let Some(instruction) = line["instruction"].as_str() {
            findings.learn(|facts| *facts.tasks.entry(instruction.into()).or_default() += 1);
        }
        let folder = format!("episode_{index:06}");
        let files = frame_files(&root.join(&folder), &rule, findings);
        episodes += u64::from(root.join(&folder).is_dir());
        frames += files;
        if files != count {
            findings.error(
                At::file(folder).episode(index),
                Check::Frames,
                format!("{files} {extension} files where episodes.jsonl states {count}"),
            );
        }
    }
    (episodes, frames)
}

/// Checks `surgvla.json` against its schema and learns the dataset's facts from it; returns the
/// points per cloud its settings allow.
fn check_metadata(root: &Path, extension: &str, findings: &Findings) -> Option<u64> {
    let mut max_points = None;
    match read_json(&root.join(super::files::SURGVLA_JSON)) {
        Ok(surgvla) => {
            max_points = surgvla["point_cloud"]["points"].as_u64();
            findings.learn(|facts| {
                facts.fps = surgvla["fps"].as_f64();
                facts.generator = surgvla["generator"].as_str().map(String::from);
                facts.collection = Collection::from_json(&surgvla["collection"]);
                let points = surgvla["point_cloud"]["points"].as_u64().unwrap_or(0) as usize;
                facts.features.push(FeatureFact {
                    name: format!("{extension} point cloud"),
                    dtype: "float32".into(),
                    shape: vec![points, 6],
                });
            });
            for (pointer, problem) in schema::check_text(&surgvla, schema::SURGVLA_META) {
                findings.error(
                    At::file(super::files::SURGVLA_JSON),
                    Check::Schema,
                    format!("{pointer} {problem}"),
                );
            }
        }
        Err(_) => findings.error(
            At::file(super::files::SURGVLA_JSON),
            Check::Present,
            "is missing or not JSON",
        ),
    }
    max_points
}

/// How a frame file is read: its format, the most points the dataset's settings allow, and
/// whether only its header is (`--quick`).
struct FrameRule {
    format: CloudFileFormat,
    max_points: Option<u64>,
    quick: bool,
}

/// Counts the `extension` files in an episode's folder and judges each
/// ([`FrameRule::problem`]).
fn frame_files(folder: &Path, rule: &FrameRule, findings: &Findings) -> u64 {
    let Ok(entries) = std::fs::read_dir(folder) else {
        findings.file_error(folder, Check::Present, "is missing");
        return 0;
    };
    let mut paths: Vec<_> = entries
        .flatten()
        .map(|entry| entry.path())
        .filter(|path| {
            path.extension()
                .is_some_and(|e| e == rule.format.extension())
        })
        .collect();
    paths.sort();
    for path in &paths {
        if let Some(problem) = rule.problem(path) {
            findings.file_error(path, Check::Cloud, problem);
        }
    }
    paths.len() as u64
}

impl FrameRule {
    /// What is wrong with the frame file at `path`: the whole file read
    /// ([`frame::frame_problem`]), or with `quick` its header and length only when those give
    /// the body's size.
    fn problem(&self, path: &Path) -> Option<String> {
        let quick = if self.quick {
            self.header_points(path)
        } else {
            Ok(None)
        };
        let points = quick.and_then(|points| match points {
            Some(points) => Ok(points),
            None => read_capped(path, frame::MAX_FRAME_BYTES)
                .map_err(|e| e.to_string())
                .and_then(|bytes| frame::frame_problem(&bytes, self.format)),
        });
        match (points, self.max_points) {
            (Err(problem), _) => Some(problem),
            (Ok(points), Some(max)) if points > max => Some(format!(
                "holds {points} points where surgvla.json's point_cloud.points allows {max}"
            )),
            _ => None,
        }
    }

    /// The points of the frame at `path` from its header and length; None when they do not
    /// give the body's size (ASCII, lists, compressed), so the body must be read.
    fn header_points(&self, path: &Path) -> Result<Option<u64>, String> {
        let file = open_regular(path).map_err(|e| e.to_string())?;
        let bytes = file.metadata().map_err(|e| e.to_string())?.len();
        let mut start = Vec::new();
        file.take(frame::MAX_HEADER_BYTES as u64)
            .read_to_end(&mut start)
            .map_err(|e| e.to_string())?;
        let header = frame::header(&start, self.format)?;
        let body = bytes.saturating_sub(header.header_bytes as u64);
        match header.body_bytes(bytes)? {
            Some(declared) if declared != body => Err(format!(
                "its body is {body} bytes where its header declares {declared}"
            )),
            Some(_) => Ok(Some(header.points)),
            None => Ok(None),
        }
    }
}
