//! Validating an RLDS dataset (a TFDS version folder): `dataset_info.json` and `features.json`
//! against their schemas, every shard present with the count `shardLengths` gives, every
//! record's framing and masked CRC-32C (all shards in parallel), then every episode decoded
//! (per-key step counts, `is_first` / `is_last` / `is_terminal` values and positions, 3-channel
//! PNGs, depth and mask sizes) with the shared semantic checks. `quick` checks the framing and
//! the first episode of each shard only.

use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::error::ExportError;
use crate::export::findings::{
    At, FeatureFact, Findings, Semantics, ValidateOptions, check_manifest, check_semantics,
};
use crate::export::paths;
use crate::export::rlds::example::{Feature, decode_example};
use crate::export::rlds::generic::{Leaf, check_record, leaves};
use crate::export::rlds::read::RldsSource;
use crate::export::rlds::tfrecord::{RecordError, RecordReader};
use crate::export::schema;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

fn schema_check(path: &Path, schema_text: &str, findings: &Findings) -> Value {
    if !path.is_file() {
        findings.file_error(path, Check::Present, "is missing");
        return Value::Null;
    }
    match read_json(path) {
        Ok(value) => {
            for (pointer, problem) in schema::check_text(&value, schema_text) {
                findings.file_error(path, Check::Schema, format!("{pointer} {problem}"));
            }
            value
        }
        Err(_) => {
            findings.file_error(path, Check::Readable, "is not valid JSON");
            Value::Null
        }
    }
}

/// Reads a shard: framing and CRCs of every record, and each record checked against the
/// features (`leaves`; images decoded in every record, or only the first when `quick`).
/// Returns (records, steps), or None when the shard is unreadable.
fn scan_shard(
    path: &Path,
    leaves: Option<&BTreeMap<String, Leaf>>,
    quick: bool,
    findings: &Findings,
) -> Option<(u64, u64)> {
    let file = crate::files::open_regular(path).ok()?;
    let mut reader = RecordReader::new(BufReader::with_capacity(1 << 20, file));
    let mut count = 0u64;
    let mut steps = 0u64;
    let at = |record: u64| At::file(findings.relative(path)).episode(record);
    while let Some(record) = reader.next_record() {
        match record {
            Ok(bytes) => {
                let example = match decode_example(&bytes) {
                    Ok(example) => example,
                    Err(error) => {
                        findings.error(
                            at(count),
                            Check::Record,
                            format!("record {count} is not a tf.train.Example: {}", error.0),
                        );
                        count += 1;
                        continue;
                    }
                };
                if let Some(Feature::Int64(first)) = example.get("steps/is_first") {
                    steps += first.len() as u64;
                }
                learn_tasks(&example, findings);
                if let Some(leaves) = leaves {
                    for (step, check, message) in
                        check_record(leaves, &example, !quick || count == 0)
                    {
                        let place = match step {
                            Some(step) => at(count).frame(step),
                            None => at(count),
                        };
                        findings.error(place, check, format!("record {count}: {message}"));
                    }
                }
                count += 1;
            }
            Err(RecordError::Io { .. }) => {
                findings.file_error(
                    path,
                    Check::Readable,
                    format!("cannot be read after record {count}"),
                );
                return None;
            }
            Err(error) => {
                findings.error(at(count), Check::Crc, error.to_string());
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
    let features = schema_check(&root.join("features.json"), schema::RLDS_FEATURES, findings);
    let leaves = match leaves(&features) {
        Ok(leaves) if !features.is_null() => Some(leaves),
        Ok(_) => None,
        Err(problem) => {
            findings.file_error(&root.join("features.json"), Check::Schema, problem);
            None
        }
    };
    let surgvla_path = root.join(super::options::SURGVLA_JSON);
    let surgvla = if surgvla_path.is_file() {
        schema_check(&surgvla_path, schema::SURGVLA_META, findings)
    } else {
        Value::Null
    };
    if let Some(data_dir) = root.parent().and_then(Path::parent) {
        let manifest = data_dir.join(super::options::MANIFEST);
        if manifest.is_file() {
            check_manifest(data_dir, super::options::MANIFEST, options.quick, findings);
        }
    }
    // Shards: the ones dataset_info.json names, and any other tfrecord file here.
    let (expected, lengths) = listed_shards(root, &dataset_info, findings);
    let count = expected.len();
    let counts: Vec<Option<(u64, u64)>> = expected
        .par_iter()
        .map(|path| {
            if !path.is_file() {
                findings.file_error(
                    path,
                    Check::Present,
                    format!("is missing (dataset_info.json lists {count} shards)"),
                );
                return None;
            }
            scan_shard(path, leaves.as_ref(), options.quick, findings)
        })
        .collect();
    for ((path, counted), listed) in expected.iter().zip(&counts).zip(&lengths) {
        match (counted, listed) {
            (Some((counted, _)), Some(listed)) if counted != listed => findings.file_error(
                path,
                Check::ShardLengths,
                format!(
                    "holds {counted} episodes where dataset_info.json's shardLengths gives {listed}"
                ),
            ),
            (_, None) => findings.file_error(
                path,
                Check::ShardLengths,
                "dataset_info.json gives no count for it",
            ),
            _ => {}
        }
    }
    let (records, steps) = counts
        .iter()
        .flatten()
        .fold((0, 0), |a, c| (a.0 + c.0, a.1 + c.1));
    learn_facts(leaves.as_ref(), &surgvla, findings);
    // Ours: the episodes through our own reader, for the semantic checks.
    if !(surgvla.is_null() || options.quick || findings.has_errors()) {
        check_our_episodes(root, &surgvla, options, findings);
    }
    (records, steps)
}

/// The most shards a split may list (TFDS numbers them with five digits).
const MAX_SHARDS: usize = 100_000;

/// The shards `dataset_info.json`'s split lists (its `train` split, else its only one: see
/// [`super::options::read_split`]), with their episode counts as listed; any other TFRecord
/// file in the folder and a split without shards being findings.
fn listed_shards(
    root: &Path,
    dataset_info: &Value,
    findings: &Findings,
) -> (Vec<PathBuf>, Vec<Option<u64>>) {
    let name = dataset_info["name"].as_str().unwrap_or_default();
    if let Err(problem) = paths::component(name) {
        findings.file_error(
            &root.join("dataset_info.json"),
            Check::Paths,
            format!("its name {name:?} cannot begin a shard's file name: it {problem}"),
        );
        return (Vec::new(), Vec::new());
    }
    let split = super::options::read_split(dataset_info);
    if split.is_none() && !dataset_info.is_null() {
        findings.file_error(
            &root.join("dataset_info.json"),
            Check::Shards,
            "lists no train split, nor one split alone named with letters, digits, _ or -",
        );
    }
    let (split_name, lengths) = split.map_or(("", Vec::new()), |(split_name, split)| {
        let lengths: Vec<Option<u64>> = (split["shardLengths"].as_array())
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
        (split_name, lengths)
    });
    let count = lengths.len();
    if count > MAX_SHARDS {
        findings.file_error(
            &root.join("dataset_info.json"),
            Check::Shards,
            format!("lists {count} shards, more than the {MAX_SHARDS} a split may have"),
        );
        return (Vec::new(), Vec::new());
    }
    let expected: Vec<PathBuf> = (0..count)
        .map(|i| root.join(format!("{name}-{split_name}.tfrecord-{i:05}-of-{count:05}")))
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
    let stray = match split {
        Some(_) => {
            format!("is not one of the {count} shards dataset_info.json's {split_name} split lists")
        }
        None => "is a TFRecord shard of no split dataset_info.json lists".to_string(),
    };
    for path in &present {
        if !expected.contains(path) {
            findings.file_error(path, Check::Shards, stray.clone());
        }
    }
    if count == 0 && split.is_some() {
        findings.file_error(
            &root.join("dataset_info.json"),
            Check::Shards,
            format!("the {split_name} split lists no shards"),
        );
    }
    (expected, lengths)
}

/// What `info` lists of an episode (a record): its first instruction, and its task id with all
/// its instructions when it records one (surgvla's `episode_metadata/task_id`).
fn learn_tasks(example: &BTreeMap<String, Feature>, findings: &Findings) {
    let text = |key: &str| match example.get(key) {
        Some(Feature::Bytes(values)) => (values.iter())
            .map(|v| String::from_utf8_lossy(v).into_owned())
            .collect(),
        _ => Vec::new(),
    };
    let instructions = text("steps/language_instruction");
    let task_id = text("episode_metadata/task_id").into_iter().next();
    findings.learn(|facts| {
        if let Some(first) = instructions.first() {
            *facts.tasks.entry(first.clone()).or_default() += 1;
        }
        if let Some(id) = task_id.filter(|id| !id.is_empty()) {
            let fact = facts.task_ids.entry(id).or_default();
            fact.episodes += 1;
            fact.instructions.extend(instructions.iter().cloned());
        }
    });
}

/// What `info` prints: the features as `features.json` declares them, and our metadata.
fn learn_facts(leaves: Option<&BTreeMap<String, Leaf>>, surgvla: &Value, findings: &Findings) {
    findings.learn(|facts| {
        facts.features = leaves
            .into_iter()
            .flatten()
            .map(|(key, leaf)| match leaf {
                Leaf::Tensor {
                    dtype, elements, ..
                } => FeatureFact {
                    name: key.clone(),
                    dtype: dtype.clone(),
                    shape: vec![*elements],
                },
                Leaf::Image { shape, dtype, .. } => FeatureFact {
                    name: key.clone(),
                    dtype: format!("image {dtype}"),
                    shape: shape.iter().map(|d| d.unwrap_or(0)).collect(),
                },
                Leaf::Text => FeatureFact {
                    name: key.clone(),
                    dtype: "text".into(),
                    shape: Vec::new(),
                },
            })
            .collect();
        facts.fps = surgvla["fps"].as_f64();
        facts.robot_type = surgvla["robot_type"].as_str().map(String::from);
        facts.generator = surgvla["generator"].as_str().map(String::from);
        facts.collection = Collection::from_json(&surgvla["collection"]);
    });
}

/// Our datasets' episodes read through our own reader, for the semantic checks.
fn check_our_episodes(
    root: &Path,
    surgvla: &Value,
    options: &ValidateOptions,
    findings: &Findings,
) {
    let source = match RldsSource::open(root) {
        Ok(source) => source,
        Err(error) => {
            findings.error(At::default(), Check::Open, error_text(&error));
            return;
        }
    };
    let Some(semantics) = Semantics::of(surgvla, options) else {
        return;
    };
    let mut episode_index = 0u64;
    for episode in source {
        match episode {
            Ok(episode) => {
                check_semantics(&episode, &semantics, &At::default(), findings);
                episode_index += 1;
            }
            Err(error) => {
                findings.error(
                    At::default().episode(episode_index),
                    Check::Record,
                    error_text(&error),
                );
                break;
            }
        }
    }
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
