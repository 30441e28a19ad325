//! Validating a folder of point-cloud files ([`super::files::CloudFilesWriter`]'s layout):
//! `surgvla.json` (our metadata, with the cloud settings and the file format), `episodes.jsonl`
//! (one line per episode), each episode's folder holding exactly the frames its line states, no
//! empty frame file, and the manifest. Returns what the folder holds, counted from the files.

use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::findings::{At, FeatureFact, Findings, ValidateOptions, check_manifest};
use crate::export::schema;
use std::path::Path;

/// Checks the folder at `root` of `extension` files; returns (episodes, frames) on disk.
pub fn check(
    root: &Path,
    extension: &str,
    options: &ValidateOptions,
    findings: &Findings,
) -> (u64, u64) {
    match read_json(&root.join(super::files::SURGVLA_JSON)) {
        Ok(surgvla) => {
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
        let files = frame_files(&root.join(&folder), extension, findings);
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

/// The non-empty `extension` files in an episode's folder; an empty one is a finding.
fn frame_files(folder: &Path, extension: &str, findings: &Findings) -> u64 {
    let Ok(entries) = std::fs::read_dir(folder) else {
        findings.file_error(folder, Check::Present, "is missing");
        return 0;
    };
    let mut count = 0;
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == extension) {
            count += 1;
            if entry.metadata().map_or(true, |m| m.len() == 0) {
                findings.file_error(&path, Check::Present, "is empty");
            }
        }
    }
    count
}
