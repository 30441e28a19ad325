//! Validating a LeRobot v3.0 or v2.1 dataset, ours or written by lerobot itself: `meta/info.json`
//! against its schema, the data files' columns exactly the declared features with their types
//! and shapes, every row (indices contiguous in row order, timestamps = frame_index / fps, task
//! indices known, numbers finite, images decodable with the declared size and channels), the
//! tasks table with its pandas index, the episodes table against the data (lengths, from/to,
//! file locations, video spans inside their files), `stats.json` present with quantiles and
//! consistent with the data, totals, the manifest, and for our datasets the semantic checks.
//! Row groups are checked in parallel; `quick` reads one frame per row group.
//!
//! `mod.rs` runs the checks and stitches row groups together; [`meta`] checks the metadata
//! files (tasks, episodes, stats, videos); [`rows`] checks the rows of one row group.

use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::findings::{
    At, FeatureFact, Findings, Semantics, ValidateOptions, check_manifest,
};
use crate::export::lerobot::meta::InfoJson;
use crate::export::schema;
use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ArrowReaderOptions};
use parts::{Context, Declared, EpisodeEntry, Part};
use rayon::prelude::*;
use serde_json::Value;
use std::path::{Path, PathBuf};

mod lint;
mod meta;

mod parts;

mod rows;

use meta::{check_stats, check_videos, read_episodes, read_tasks};

fn declared_features(info: &InfoJson) -> Vec<Declared> {
    info.feature_list()
        .into_iter()
        .map(|(name, f)| Declared {
            dtype: f.dtype().to_string(),
            shape: f.shape().to_vec(),
            name,
        })
        .collect()
}

/// Checks the LeRobot dataset at `root`; returns (episodes, frames) found.
pub fn check(root: &Path, v21: bool, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
    let (info, info_known) = read_info(root, findings);
    let features = declared_features(&info);
    let fps = info.fps_hz();
    findings.learn(|facts| {
        facts.fps = fps;
        facts.robot_type = info.robot_type.clone();
        facts.features = features
            .iter()
            .map(|f| FeatureFact {
                name: f.name.clone(),
                dtype: f.dtype.clone(),
                shape: f.shape.clone(),
            })
            .collect();
    });
    let surgvla = check_our_metadata(root, findings);
    let semantics = Semantics::of(&surgvla, options);
    let rewritten = check_manifest(root, crate::export::dir::MANIFEST, options.quick, findings);
    // As surgvla wrote it: what our writer always writes is required.
    let as_written = !surgvla.is_null() && !rewritten;
    let tasks = read_tasks(root, v21, findings);
    let entries = read_episodes(root, v21, &features, as_written, findings);
    learn_tasks(&tasks, &entries, findings);
    if !surgvla.is_null() {
        check_provenance(&entries, v21, findings);
    }
    let files = super::read::data_files(root).unwrap_or_default();
    if files.is_empty() {
        findings.error(
            At::file("data"),
            Check::Present,
            "no data files (data/chunk-*/*.parquet)",
        );
    }
    let context = Context {
        root,
        features: &features,
        fps,
        tasks: tasks.len(),
        quick: options.quick,
        entries: &entries,
        task_names: &tasks,
        semantics: semantics.as_ref(),
        findings,
        info_known,
        as_written,
        lint: options.lint,
    };
    let (episodes, frames, mut parts) = check_data_files(&context, &files, &info, v21);
    check_stats(root, &features, &parts, as_written, findings);
    let videos = check_videos(
        root,
        v21,
        &info,
        &features,
        &entries,
        (options.quick, as_written, options.lint),
        findings,
    );
    if options.lint {
        let known = lint::Known {
            info: &info,
            features: &features,
            tasks: &tasks,
            entries: &entries,
            semantics: semantics.as_ref(),
        };
        lint::lint(&known, &mut parts, videos, findings);
    }
    (episodes, frames)
}

/// Every row group of every data file, in order, checked in parallel (each file's footer read
/// once and shared by its row groups), then stitched into episodes: (episodes, frames, what each
/// row group held).
fn check_data_files(
    context: &Context<'_>,
    files: &[PathBuf],
    info: &InfoJson,
    v21: bool,
) -> (u64, u64, Vec<Part>) {
    let metadata: Vec<Option<ArrowReaderMetadata>> = files
        .par_iter()
        .map(|path| open_metadata(path, context.findings))
        .collect();
    let groups: Vec<(usize, usize)> = metadata
        .iter()
        .enumerate()
        .flat_map(|(f, m)| {
            let count = m.as_ref().map_or(0, |m| m.metadata().num_row_groups());
            (0..count).map(move |g| (f, g))
        })
        .collect();
    let parts: Vec<Part> = groups
        .par_iter()
        .filter_map(|&(f, g)| Some(context.check_row_group(&files[f], metadata[f].as_ref()?, g)))
        .collect();
    let (episodes, frames) = stitch(context, files, &groups, &parts, info, v21);
    (episodes, frames, parts)
}

/// `meta/info.json` checked against its schema and read leniently (a field of the wrong type
/// reads as absent: the schema check has named it); whether it could be read at all.
fn read_info(root: &Path, findings: &Findings) -> (InfoJson, bool) {
    let info_path = root.join("meta/info.json");
    if !info_path.is_file() {
        findings.file_error(
            &info_path,
            Check::Present,
            "is missing: the loader cannot open the dataset",
        );
        return (InfoJson::default(), false);
    }
    match read_json(&info_path) {
        Ok(info) => {
            for (pointer, problem) in schema::check_text(&info, schema::LEROBOT_INFO) {
                findings.file_error(&info_path, Check::Schema, format!("{pointer} {problem}"));
            }
            (serde_json::from_value(info).unwrap_or_default(), true)
        }
        Err(_) => {
            findings.file_error(&info_path, Check::Readable, "is not valid JSON");
            (InfoJson::default(), false)
        }
    }
}

/// Our own metadata (`meta/surgvla.json`) and collect report checked against their schemas when
/// present; returns the metadata (`Null` when absent: another tool's dataset).
fn check_our_metadata(root: &Path, findings: &Findings) -> Value {
    let checked = |relative: &str, schema: &str| {
        let value = read_optional_json(root, relative, findings);
        if !value.is_null() {
            let path = root.join(relative);
            for (pointer, problem) in schema::check_text(&value, schema) {
                findings.file_error(&path, Check::Schema, format!("{pointer} {problem}"));
            }
        }
        value
    };
    let surgvla = checked("meta/surgvla.json", schema::SURGVLA_META);
    checked("collect_report.json", schema::COLLECT_REPORT);
    findings.learn(|facts| {
        facts.generator = surgvla["generator"].as_str().map(String::from);
        facts.collection = Collection::from_json(&surgvla["collection"]);
    });
    surgvla
}

/// The tasks and how many episodes each has (for `info`).
fn learn_tasks(tasks: &[String], entries: &[EpisodeEntry], findings: &Findings) {
    findings.learn(|facts| {
        for task in tasks {
            facts.tasks.insert(task.clone(), 0);
        }
        for entry in entries {
            if let Some(task) = entry.tasks.first() {
                *facts.tasks.entry(task.clone()).or_default() += 1;
            }
            let id = entry
                .provenance
                .get("surgvla/task_id")
                .and_then(Value::as_str);
            if let Some(id) = id.filter(|id| !id.is_empty()) {
                let fact = facts.task_ids.entry(id.to_string()).or_default();
                fact.episodes += 1;
                fact.instructions.extend(entry.tasks.iter().cloned());
            }
        }
    });
}

/// Our datasets record each episode's provenance in the episodes table.
fn check_provenance(entries: &[EpisodeEntry], v21: bool, findings: &Findings) {
    for (i, entry) in entries.iter().enumerate() {
        for key in super::table::Provenance::KEYS {
            if !entry.provenance.contains_key(key) {
                findings.error(
                    At::file(episodes_file(v21)).episode(i as u64),
                    Check::Provenance,
                    format!("the episodes table has no {key}"),
                );
            }
        }
    }
}

pub(super) fn episodes_file(v21: bool) -> &'static str {
    if v21 {
        "meta/episodes.jsonl"
    } else {
        "meta/episodes/chunk-000/file-000.parquet"
    }
}

fn read_optional_json(root: &Path, relative: &str, findings: &Findings) -> Value {
    let path = root.join(relative);
    if !path.is_file() {
        return Value::Null;
    }
    read_json(&path).unwrap_or_else(|_| {
        findings.file_error(&path, Check::Readable, "is not valid JSON");
        Value::Null
    })
}

/// A data file's parquet metadata (its footer), or a finding naming the file.
fn open_metadata(path: &Path, findings: &Findings) -> Option<ArrowReaderMetadata> {
    let opened = crate::files::open_regular(path)
        .map_err(|e| e.to_string())
        .and_then(|f| {
            let file_bytes = f.metadata().map_err(|e| e.to_string())?.len();
            let metadata = ArrowReaderMetadata::load(&f, ArrowReaderOptions::default())
                .map_err(|e| e.to_string())?;
            if let Some(problem) = super::read::footer_problem(metadata.metadata(), file_bytes) {
                return Err(problem);
            }
            Ok(with_image_views(metadata))
        });
    match opened {
        Ok(metadata) => Some(metadata),
        Err(problem) => {
            findings.file_error(
                path,
                Check::Readable,
                format!("is not a readable parquet file: {problem}"),
            );
            None
        }
    }
}

/// The file read with its images' `bytes` as views into the decoded pages (`BinaryView`), not
/// copied out of them: the full pass's largest copy. Unchanged when another schema cannot be
/// applied (the reader then reports the file as it is).
fn with_image_views(metadata: ArrowReaderMetadata) -> ArrowReaderMetadata {
    use arrow_schema::{DataType, Field, Schema};
    let schema = metadata.schema();
    let viewed = |field: &Field| -> Option<Field> {
        let DataType::Struct(children) = field.data_type() else {
            return None;
        };
        let bytes = children.find("bytes")?.1;
        (bytes.data_type() == &DataType::Binary).then(|| {
            let children: Vec<Field> = (children.iter())
                .map(|c| match c.name().as_str() {
                    "bytes" => c.as_ref().clone().with_data_type(DataType::BinaryView),
                    _ => c.as_ref().clone(),
                })
                .collect();
            field
                .clone()
                .with_data_type(DataType::Struct(children.into()))
        })
    };
    if !schema.fields().iter().any(|f| viewed(f).is_some()) {
        return metadata;
    }
    let fields: Vec<Field> = (schema.fields().iter())
        .map(|f| viewed(f).unwrap_or_else(|| f.as_ref().clone()))
        .collect();
    let hinted = Schema::new_with_metadata(fields, schema.metadata().clone());
    let options = ArrowReaderOptions::new().with_schema(std::sync::Arc::new(hinted));
    ArrowReaderMetadata::try_new(metadata.metadata().clone(), options).unwrap_or(metadata)
}

/// One whole episode as the rows hold it: (episode, first index, last index, rows, file).
type EpisodeSpan = (i64, i64, i64, u64, usize);

/// The cross-row-group checks: indices contiguous across groups and files, episodes contiguous,
/// the episodes table and the totals against the data (every row's indices are read, quick or
/// not). Returns (episodes, frames).
fn stitch(
    context: &Context<'_>,
    files: &[PathBuf],
    groups: &[(usize, usize)],
    parts: &[Part],
    info: &InfoJson,
    v21: bool,
) -> (u64, u64) {
    let (episodes, frames) = assemble_episodes(context, files, groups, parts);
    check_episodes_table(context, files, &episodes, v21);
    check_table_files(context, &episodes, info, v21);
    check_totals(context, info, episodes.len() as u64, frames);
    (episodes.len() as u64, frames)
}

/// The row groups' runs joined into whole episodes, in row order: indices contiguous, episodes
/// in order, each starting at frame 0. Returns the episodes and the rows read.
fn assemble_episodes(
    context: &Context<'_>,
    files: &[PathBuf],
    groups: &[(usize, usize)],
    parts: &[Part],
) -> (Vec<EpisodeSpan>, u64) {
    let findings = context.findings;
    // Whole episodes: (episode, first_index, last_index, rows, file).
    let mut episodes: Vec<EpisodeSpan> = Vec::new();
    let mut frames = 0u64;
    for (&(file, _), part) in groups.iter().zip(parts) {
        frames += part.rows;
        for run in &part.runs {
            let relative = findings.relative(&files[file]);
            let at = || At::file(relative.clone()).episode(run.episode.max(0) as u64);
            match episodes.last_mut() {
                Some(last) if last.0 == run.episode => {
                    if run.first_index != last.2 + 1 {
                        findings.error(
                            at(),
                            Check::Index,
                            format!("index {} follows {}", run.first_index, last.2),
                        );
                    }
                    last.2 = run.last_index;
                    last.3 += run.rows;
                }
                previous => {
                    let previous = previous.map(|p| (p.0, p.2));
                    let expected = previous.map_or(0, |p| p.0 + 1);
                    if run.episode != expected {
                        findings.error(
                            at(),
                            Check::EpisodeIndex,
                            format!(
                                "episode {} follows episode {} in row order",
                                run.episode,
                                expected - 1
                            ),
                        );
                    }
                    let expected_index = previous.map_or(0, |p| p.1 + 1);
                    if run.first_index != expected_index {
                        findings.error(
                            at(),
                            Check::Index,
                            format!(
                                "the episode starts at index {} where {expected_index} was next",
                                run.first_index
                            ),
                        );
                    }
                    if run.first_frame != 0 {
                        findings.error(
                            at(),
                            Check::FrameIndex,
                            format!("the episode starts at frame_index {}", run.first_frame),
                        );
                    }
                    episodes.push((run.episode, run.first_index, run.last_index, run.rows, file));
                }
            }
        }
    }
    (episodes, frames)
}

/// The episodes table against the data: its row count, each episode's length, span, data
/// file and tasks.
fn check_episodes_table(
    context: &Context<'_>,
    files: &[PathBuf],
    episodes: &[EpisodeSpan],
    v21: bool,
) {
    let findings = context.findings;
    let entries = context.entries;
    let episodes_file = episodes_file(v21);
    if entries.len() != episodes.len() {
        findings.error(
            At::file(episodes_file),
            Check::Episodes,
            format!(
                "the episodes table has {} rows, the data {} episodes",
                entries.len(),
                episodes.len()
            ),
        );
    }
    for &(episode, first, last, rows, file) in episodes {
        let Some(entry) = entries.get(episode.max(0) as usize) else {
            continue;
        };
        let at = || At::file(episodes_file).episode(episode.max(0) as u64);
        if entry.length != Some(rows as i64) {
            findings.error(
                at(),
                Check::Length,
                format!("length {:?}, the data holds {rows} frames", entry.length),
            );
        }
        if !v21 {
            if entry.from != Some(first) {
                findings.error(
                    at(),
                    Check::FromTo,
                    format!(
                        "dataset_from_index {:?}, the episode's first index is {first}",
                        entry.from
                    ),
                );
            }
            if entry.to != Some(last + 1) {
                findings.error(at(), Check::FromTo, format!("dataset_to_index {:?}, the episode's last index is {last} (to is exclusive)", entry.to));
            }
            if let Some((chunk, data_file)) = entry.data_file {
                let expected = format!("data/chunk-{chunk:03}/file-{data_file:03}.parquet");
                if findings.relative(&files[file]) != expected {
                    findings.error(at(), Check::Location, format!("data/chunk_index, data/file_index name {expected}, the episode is in {}", findings.relative(&files[file])));
                }
            }
        }
        // Others' tables may lack the column (a warning has said so).
        if entry.tasks.is_empty() && context.as_written {
            findings.error(at(), Check::Tasks, "the episode lists no task");
        }
        for task in &entry.tasks {
            if !context.task_names.contains(task) {
                findings.error(
                    at(),
                    Check::Tasks,
                    format!("task {task:?} is not in the tasks table"),
                );
            }
        }
    }
}

/// Every data file the episodes table names is present (v2.1: one per episode), and no episode
/// has zero frames.
fn check_table_files(context: &Context<'_>, episodes: &[EpisodeSpan], info: &InfoJson, v21: bool) {
    let findings = context.findings;
    let entries = context.entries;
    let episodes_file = episodes_file(v21);
    for (i, entry) in entries.iter().enumerate() {
        if let Some((chunk, file)) = entry.data_file
            && !v21
        {
            let path = context
                .root
                .join(format!("data/chunk-{chunk:03}/file-{file:03}.parquet"));
            if !path.is_file() {
                findings.error(
                    At::file(findings.relative(&path)).episode(i as u64),
                    Check::Present,
                    "is missing (the episodes table names it)",
                );
            }
        }
        if v21 && i >= episodes.len() {
            let chunks_size = info.chunks_size.unwrap_or(1000).max(1) as usize;
            let path = context.root.join(format!(
                "data/chunk-{:03}/episode_{i:06}.parquet",
                i / chunks_size
            ));
            if !path.is_file() {
                findings.error(
                    At::file(findings.relative(&path)).episode(i as u64),
                    Check::Present,
                    "is missing",
                );
            }
        }
        if entry.length == Some(0) {
            findings.error(
                At::file(episodes_file).episode(i as u64),
                Check::Steps,
                "the episode has zero frames",
            );
        }
    }
}

/// info.json's totals against the data and the tasks table.
fn check_totals(context: &Context<'_>, info: &InfoJson, episodes: u64, frames: u64) {
    let findings = context.findings;
    if let Some(total) = info.total_episodes
        && total != episodes
    {
        findings.error(
            At::file("meta/info.json"),
            Check::Totals,
            format!("total_episodes is {total}, the data holds {episodes}"),
        );
    }
    if let Some(total) = info.total_frames
        && total != frames
    {
        findings.error(
            At::file("meta/info.json"),
            Check::Totals,
            format!("total_frames is {total}, the data holds {frames}"),
        );
    }
    if let Some(total) = info.total_tasks
        && total != context.tasks as u64
    {
        findings.error(
            At::file("meta/info.json"),
            Check::Totals,
            format!(
                "total_tasks is {total}, the tasks table holds {}",
                context.tasks
            ),
        );
    }
}
