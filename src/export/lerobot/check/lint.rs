//! The quality lint of a LeRobot dataset: the series each row group gathered joined into
//! episodes, the dataset as the lint needs it (features and their names, fps, instructions,
//! splits, provenance), then [`crate::export::lint::lint`].

use super::parts::{Declared, EpisodeEntry, LINT_MAX_DIMS, Part, is_index_column};
use crate::export::findings::{Findings, Semantics};
use crate::export::lerobot::meta::InfoJson;
use crate::export::lint::cameras::CameraFrames;
use crate::export::lint::{EpisodeSeries, LintDataset, LintFeature};
use serde_json::Value;
use std::collections::BTreeMap;

/// What the lint reads of the dataset besides the row groups.
pub(super) struct Known<'a> {
    pub(super) info: &'a InfoJson,
    pub(super) features: &'a [Declared],
    pub(super) tasks: &'a [String],
    pub(super) entries: &'a [EpisodeEntry],
    pub(super) semantics: Option<&'a Semantics>,
}

/// Lints the dataset from its row groups' series (in row order) and its cameras' frames.
pub(super) fn lint(
    known: &Known<'_>,
    parts: &mut [Part],
    videos: Vec<CameraFrames>,
    findings: &Findings,
) {
    let mut episodes: BTreeMap<i64, EpisodeSeries> = BTreeMap::new();
    let mut cameras: BTreeMap<(u64, String), CameraFrames> = BTreeMap::new();
    for part in parts.iter_mut() {
        for (episode, series) in std::mem::take(&mut part.series) {
            let joined = episodes.entry(episode).or_default();
            joined.episode = series.episode;
            joined.task = joined.task.or(series.task);
            joined.timestamps_secs.extend(series.timestamps_secs);
            for (name, values) in series.features {
                let into = joined.features.entry(name).or_default();
                into.dims = values.dims;
                into.values.extend(values.values);
            }
        }
        for (episode, key, shape, look) in std::mem::take(&mut part.looks) {
            let camera = cameras
                .entry((episode.max(0) as u64, key.clone()))
                .or_insert_with(|| CameraFrames {
                    episode: episode.max(0) as u64,
                    camera: key,
                    shape,
                    frames: Vec::new(),
                });
            camera.frames.push(look);
        }
    }
    let mut cameras: Vec<CameraFrames> = cameras.into_values().chain(videos).collect();
    for camera in &mut cameras {
        camera.frames.sort_by_key(|f| f.frame);
    }
    let episodes: Vec<EpisodeSeries> = episodes.into_values().collect();
    crate::export::lint::lint(&dataset(known), &episodes, &cameras, "data", findings);
}

fn dataset(known: &Known<'_>) -> LintDataset {
    let declared: BTreeMap<String, Value> = (known.info.feature_list().into_iter())
        .map(|(name, f)| (name, f.names))
        .collect();
    let features = (known.features.iter())
        .filter(|f| matches!(f.dtype.as_str(), "float32" | "float64"))
        .filter(|f| !is_index_column(&f.name) && f.elements() <= LINT_MAX_DIMS)
        .map(|f| {
            let names = names_of(declared.get(&f.name).unwrap_or(&Value::Null));
            LintFeature {
                name: f.name.clone(),
                dims: f.elements(),
                names: if names.len() == f.elements() {
                    names
                } else {
                    Vec::new()
                },
            }
        })
        .collect();
    let splits = known.info.split_ranges();
    let seeds = (known.entries.iter().enumerate())
        .filter_map(|(i, entry)| {
            let seed = entry.provenance.get("surgvla/seed")?.as_u64()?;
            let task = entry.provenance.get("surgvla/task_id")?.as_str()?;
            Some((i as u64, (task.to_string(), seed)))
        })
        .collect();
    LintDataset {
        fps: known.info.fps_hz(),
        features,
        timestamp_f32: known
            .features
            .iter()
            .any(|f| f.name == "timestamp" && f.dtype == "float32"),
        instructions: known.tasks.to_vec(),
        gripper: known.semantics.and_then(|s| s.gripper),
        splits,
        seeds,
    }
}

/// A feature's `names`: a list of strings, or lerobot's `{"motors": [...]}` (one list).
fn names_of(value: &Value) -> Vec<String> {
    let list = match value {
        Value::Array(list) => Some(list),
        Value::Object(map) if map.len() == 1 => map.values().next().and_then(Value::as_array),
        _ => None,
    };
    list.map(|l| {
        l.iter()
            .filter_map(|v| v.as_str().map(str::to_string))
            .collect()
    })
    .unwrap_or_default()
}
