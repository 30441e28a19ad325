//! What the LeRobot checks share: the declared features, the episodes table's entries, the
//! parts (row groups) the data is checked in, and reading a parquet table for a check.

use crate::export::check::Check;
use crate::export::findings::{Findings, Semantics};
use crate::export::lint::EpisodeSeries;
use crate::export::lint::cameras::FrameLook;
use arrow_array::RecordBatch;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// The statistics lerobot's normalisation reads for every feature.
pub(super) const STATS_KEYS: [&str; 10] = [
    "min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99",
];

/// Timestamps may differ from frame_index / fps by this much (lerobot's tolerance).
pub(super) const TIMESTAMP_TOLERANCE_SECS: f64 = 1e-4;

/// A declared feature.
#[derive(Clone, Debug)]
pub(super) struct Declared {
    pub(super) name: String,
    pub(super) dtype: String,
    pub(super) shape: Vec<usize>,
}

impl Declared {
    pub(super) fn elements(&self) -> usize {
        self.shape.iter().product::<usize>().max(1)
    }
}

/// One episode as the episodes metadata describes it.
#[derive(Clone, Debug, Default)]
pub(super) struct EpisodeEntry {
    pub(super) length: Option<i64>,
    pub(super) from: Option<i64>,
    pub(super) to: Option<i64>,
    pub(super) data_file: Option<(i64, i64)>,
    pub(super) tasks: Vec<String>,
    /// Video key -> (chunk, file, from_secs, to_secs).
    pub(super) videos: BTreeMap<String, (i64, i64, f64, f64)>,
    pub(super) provenance: BTreeMap<String, Value>,
}

/// A run of consecutive rows of one episode in one row group.
#[derive(Clone, Debug)]
pub(super) struct Run {
    pub(super) episode: i64,
    pub(super) first_index: i64,
    pub(super) last_index: i64,
    pub(super) first_frame: i64,
    pub(super) last_frame: i64,
    pub(super) rows: u64,
}

/// Per element of a numeric feature: (min, max, sum, count).
pub(super) type Moments = Vec<(f64, f64, f64, u64)>;

/// What one row group held.
#[derive(Debug, Default)]
pub(super) struct Part {
    pub(super) runs: Vec<Run>,
    pub(super) rows: u64,
    pub(super) moments: BTreeMap<String, Moments>,
    /// The lint's series of the row group's episodes (lint on).
    pub(super) series: BTreeMap<i64, EpisodeSeries>,
    /// The lint's look at each decoded image: (episode, feature, (w, h, c), look).
    pub(super) looks: Vec<ImageLook>,
}

/// The lint's look at one decoded image: (episode, feature, (w, h, c), look).
pub(super) type ImageLook = (i64, String, (usize, usize, usize), FrameLook);

/// Numeric features with more values than this per frame are not linted.
pub(super) const LINT_MAX_DIMS: usize = 64;

/// Reads every batch of a parquet file, or names the file in a finding.
pub(super) fn read_table(path: &Path, findings: &Findings) -> Option<Vec<RecordBatch>> {
    match crate::export::lerobot::read::read_parquet(path) {
        Ok(batches) => Some(batches),
        Err(_) => {
            findings.file_error(path, Check::Readable, "is not a readable parquet file");
            None
        }
    }
}

pub(super) fn is_index_column(name: &str) -> bool {
    name == "timestamp" || INDEX_COLUMNS.contains(&name)
}

/// What every row group's check needs.
pub(super) struct Context<'a> {
    pub(super) root: &'a Path,
    pub(super) features: &'a [Declared],
    pub(super) fps: Option<f64>,
    pub(super) tasks: usize,
    pub(super) quick: bool,
    pub(super) entries: &'a [EpisodeEntry],
    pub(super) task_names: &'a [String],
    pub(super) semantics: Option<&'a Semantics>,
    pub(super) findings: &'a Findings,
    pub(super) info_known: bool,
    /// A dataset surgvla wrote, unedited since (see `check_manifest`): what our writer always
    /// writes is required.
    pub(super) as_written: bool,
    /// Gather what the quality lint judges.
    pub(super) lint: bool,
}

/// The columns every LeRobot frame has besides its features.
pub(super) const INDEX_COLUMNS: [&str; 4] = ["frame_index", "episode_index", "index", "task_index"];
