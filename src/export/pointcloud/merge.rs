//! The point-cloud folders' merge: a frame's file holds no episode number, so every file is
//! copied as it is (once [`super::frame::frame_problem`] finds nothing wrong with it) under its
//! new episode's folder (`episode_NNNNNN/frame_NNNNNN.ply|pcd`);
//! `episodes.jsonl` gets each line again with its new `episode_index` (the other keys as they
//! were, in their order), `surgvla.json` the merged collection
//! ([`crate::export::merge::merge_episode_files`]). N of N merged are the single run's bytes.
//! `--resume` starts an interrupted point-cloud merge over in its folder
//! ([`crate::export::merge::output_dir`]).

use super::files::{CloudFileFormat, EPISODES, MANIFEST, SURGVLA_JSON};
use super::frame::{MAX_FRAME_BYTES, frame_problem};
use crate::export::bounded::read_capped;
use crate::export::bounded::read_json;
use crate::export::collection::Collection;
use crate::export::convert::ConvertError;
use crate::export::dir::DatasetDir;
use crate::export::error::ExportError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::merge::{Part, merge_episode_files, plan};
use crate::export::sink::Summary;
use serde_json::Value;
use std::path::Path;

/// Merges the request's point-cloud folders into a new one at its `out` (see the module
/// overview).
pub(super) fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let mut parts = Vec::new();
    let mut first_surgvla = None;
    for path in request.inputs {
        let surgvla = read_json(&path.join(SURGVLA_JSON)).map_err(read)?;
        parts.push(Part::read(
            path,
            &path.join(MANIFEST),
            Collection::from_json(&surgvla["collection"]),
        )?);
        first_surgvla.get_or_insert(surgvla);
    }
    let plan = plan(parts)?;
    let format = match plan.options.format() {
        Some("pcd") => CloudFileFormat::Pcd,
        _ => CloudFileFormat::Ply,
    };
    let extension = format.extension();
    let mut surgvla = first_surgvla.ok_or(MergeError::NoInput)?;
    if let Some(collection) = &plan.collection {
        surgvla["collection"] = collection.to_json();
    }
    let surgvla = serde_json::to_vec_pretty(&surgvla).map_err(|source| {
        write(ExportError::Json {
            path: request.out.join(SURGVLA_JSON),
            source,
        })
    })?;
    let lines: Vec<Vec<(Value, u64)>> = plan
        .parts
        .iter()
        .map(|p| crate::export::merge::episode_lines(&p.path, EPISODES))
        .collect::<Result<_, _>>()?;
    // Each episode's frames, by input and episode: checked before anything is written.
    let mut frames = std::collections::HashMap::new();
    for (part, lines) in plan.parts.iter().zip(&lines) {
        for (k, (_, count)) in lines.iter().enumerate() {
            let last = format!("episode_{k:06}/frame_{:06}.{extension}", count - 1);
            if !part.path.join(&last).is_file() {
                return Err(read(ExportError::InvalidDataset {
                    path: part.path.join(EPISODES),
                    problem: format!("episode {k} says {count} frames, but {last} is missing"),
                }));
            }
            frames.insert((part.path.clone(), k as u64), *count);
        }
    }
    let mut copy = |dir: &mut DatasetDir, root: &Path, from: u64, to: u64| {
        let count = frames
            .get(&(root.to_path_buf(), from))
            .copied()
            .unwrap_or(0);
        for frame in 0..count {
            let source = root.join(format!("episode_{from:06}/frame_{frame:06}.{extension}"));
            let bytes = read_capped(&source, MAX_FRAME_BYTES).map_err(read)?;
            // A frame that plyfile or PCL could not read is never copied into a valid-looking
            // dataset.
            if let Err(problem) = frame_problem(&bytes, format) {
                return Err(read(ExportError::InvalidDataset {
                    path: source,
                    problem,
                }));
            }
            let target = format!("episode_{to:06}/frame_{frame:06}.{extension}");
            dir.write_atomically(&target, &bytes).map_err(write)?;
        }
        Ok(())
    };
    merge_episode_files(
        request,
        &plan,
        EPISODES,
        &|_| String::new(),
        &mut copy,
        &[(SURGVLA_JSON, surgvla)],
        MANIFEST,
    )
}
