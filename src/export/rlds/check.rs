//! Validating an RLDS dataset (a TFDS version folder): `dataset_info.json` and `features.json`
//! against their schemas, every shard present with the count `shardLengths` gives, every
//! record's framing and masked CRC-32C (all shards in parallel), then every episode decoded
//! (per-key step counts, `is_first` / `is_last` / `is_terminal` values and positions, 3-channel
//! PNGs, depth and mask sizes) with the shared semantic checks. `quick` checks the framing and
//! the first episode of each shard only.

use crate::export::rlds::example::{Feature, decode_example};
use crate::export::rlds::read::RldsSource;
use crate::export::rlds::tfrecord::{RecordError, RecordReader};
use crate::export::validate::{
    At, FeatureFact, Findings, Semantics, ValidateOptions, check_manifest, check_semantics,
};
use crate::export::{EpisodeSource, ExportError, read_json, schema};
use rayon::prelude::*;
use serde_json::Value;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

fn schema_check(path: &Path, schema_text: &str, findings: &Findings) -> Value {
    if !path.is_file() {
        findings.file_error(path, "present", "is missing");
        return Value::Null;
    }
    match read_json(path) {
        Ok(value) => {
            for (pointer, problem) in schema::check_text(&value, schema_text) {
                findings.file_error(path, "schema", format!("{pointer} {problem}"));
            }
            value
        }
        Err(_) => {
            findings.file_error(path, "readable", "is not valid JSON");
            Value::Null
        }
    }
}

/// Counts a shard's records and their steps (`steps/is_first` entries), checking framing and
/// CRCs; None when unreadable.
fn count_records(path: &Path, findings: &Findings) -> Option<(u64, u64)> {
    let file = File::open(path).ok()?;
    let mut reader = RecordReader::new(BufReader::with_capacity(1 << 20, file));
    let mut count = 0u64;
    let mut steps = 0u64;
    while let Some(record) = reader.next_record() {
        match record {
            Ok(bytes) => {
                count += 1;
                if let Ok(example) = decode_example(&bytes)
                    && let Some(Feature::Int64(first)) = example.get("steps/is_first")
                {
                    steps += first.len() as u64;
                }
            }
            Err(RecordError::Io { .. }) => {
                findings.file_error(
                    path,
                    "readable",
                    format!("cannot be read after record {count}"),
                );
                return None;
            }
            Err(error) => {
                findings.error(
                    At::file(findings.relative(path)).episode(count),
                    "crc",
                    format!("record {count}: {error}"),
                );
                return None;
            }
        }
    }
    Some((count, steps))
}

/// Checks the RLDS version folder `root`; returns (episodes, frames).
pub fn check(root: &Path, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
    let dataset_info = schema_check(
        &root.join("dataset_info.json"),
        schema::RLDS_DATASET_INFO,
        findings,
    );
    schema_check(&root.join("features.json"), schema::RLDS_FEATURES, findings);
    let surgvla_path = root.join(super::SURGVLA_JSON);
    let surgvla = if surgvla_path.is_file() {
        schema_check(&surgvla_path, schema::SURGVLA_META, findings)
    } else {
        Value::Null
    };
    if let Some(data_dir) = root.parent().and_then(Path::parent) {
        let manifest = data_dir.join(super::MANIFEST);
        if manifest.is_file() {
            check_manifest(data_dir, super::MANIFEST, findings);
        }
    }
    // Shards: the ones dataset_info.json names, and any other tfrecord file here.
    let name = dataset_info["name"].as_str().unwrap_or_default();
    let lengths: Vec<Option<u64>> = dataset_info["splits"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["name"] == "train"))
        .and_then(|s| s["shardLengths"].as_array())
        .map(|l| {
            l.iter()
                .map(|v| {
                    v.as_str()
                        .and_then(|s| s.parse().ok())
                        .or_else(|| v.as_u64())
                })
                .collect()
        })
        .unwrap_or_default();
    let count = lengths.len();
    let expected: Vec<PathBuf> = (0..count)
        .map(|i| root.join(format!("{name}-train.tfrecord-{i:05}-of-{count:05}")))
        .collect();
    let present: Vec<PathBuf> = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().contains(".tfrecord-"))
        })
        .collect();
    for path in &present {
        if !expected.contains(path) {
            findings.file_error(
                path,
                "shards",
                format!("is not one of the {count} shards dataset_info.json's train split lists"),
            );
        }
    }
    if count == 0 && !dataset_info.is_null() {
        findings.file_error(
            &root.join("dataset_info.json"),
            "shards",
            "the train split lists no shards",
        );
    }
    let counts: Vec<Option<(u64, u64)>> = expected
        .par_iter()
        .map(|path| {
            if !path.is_file() {
                findings.file_error(
                    path,
                    "present",
                    format!("is missing (dataset_info.json lists {count} shards)"),
                );
                return None;
            }
            count_records(path, findings)
        })
        .collect();
    for ((path, counted), listed) in expected.iter().zip(&counts).zip(&lengths) {
        match (counted, listed) {
            (Some((counted, _)), Some(listed)) if counted != listed => findings.file_error(
                path,
                "shard_lengths",
                format!(
                    "holds {counted} episodes where dataset_info.json's shardLengths gives {listed}"
                ),
            ),
            (_, None) => findings.file_error(
                path,
                "shard_lengths",
                "dataset_info.json gives no count for it",
            ),
            _ => {}
        }
    }
    // Content: every episode through the source (it stops at the first defect it meets).
    let mut episodes = 0u64;
    let mut frames = 0u64;
    if findings.has_errors() {
        return counts
            .iter()
            .flatten()
            .fold((0, 0), |a, c| (a.0 + c.0, a.1 + c.1));
    }
    let mut source = match RldsSource::open(root) {
        Ok(source) => source,
        Err(error) => {
            findings.error(At::default(), "open", error_text(&error));
            return (0, 0);
        }
    };
    let semantics = Semantics::of(&surgvla, options);
    let info = source.info();
    findings.learn(|facts| {
        facts.fps = Some(f64::from(info.fps)).filter(|f| *f > 0.0);
        facts.robot_type = Some(info.robot_type.clone()).filter(|r| !r.is_empty());
        facts.features = info
            .features
            .iter()
            .map(|f| FeatureFact {
                name: f.name.clone(),
                dtype: format!("{:?}", f.dtype).to_lowercase(),
                shape: f.shape.clone(),
            })
            .collect();
        facts.generator = surgvla["generator"].as_str().map(String::from);
        facts.collection = surgvla["collection"].clone();
    });
    let limit = if options.quick { 1 } else { u64::MAX };
    while let Some(episode) = source.next_episode() {
        match episode {
            Ok(episode) => {
                frames += episode.steps.len() as u64;
                findings.learn(|facts| {
                    *facts
                        .tasks
                        .entry(episode.meta.instruction.clone())
                        .or_default() += 1
                });
                check_semantics(&episode, semantics.as_ref(), &At::default(), findings);
                episodes += 1;
                if episodes >= limit {
                    break;
                }
            }
            Err(error) => {
                findings.error(
                    At::default().episode(episodes),
                    "record",
                    error_text(&error),
                );
                break;
            }
        }
    }
    if options.quick {
        (episodes, frames) = counts
            .iter()
            .flatten()
            .fold((0, 0), |a, c| (a.0 + c.0, a.1 + c.1));
    }
    (episodes, frames)
}

/// An error's message with its causes.
fn error_text(error: &ExportError) -> String {
    let mut text = error.to_string();
    let mut source = std::error::Error::source(error);
    while let Some(cause) = source {
        text.push_str(": ");
        text.push_str(&cause.to_string());
        source = cause.source();
    }
    text
}
