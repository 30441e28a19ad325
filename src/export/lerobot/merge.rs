//! Merging LeRobot datasets (the outputs of `collect --shard I/N`, or any compatible ones) into
//! one: every input's episodes in turn, re-indexed, through one LeRobot writer, so files roll by
//! size and the statistics are recomputed over the merged data in global order (quantiles
//! exact, never averaged). Video is copied frame for frame, not decoded: its statistics come
//! from the exact per-episode accumulators surgvla stores beside video episodes (another tool's
//! video datasets have only per-episode summaries, merged by count with approximate
//! quantiles). Inputs must agree on everything that shapes the bytes (features, fps,
//! robot, camera, mask ids, collection options, layout); shards of one collection are put in
//! shard order, and when they are all N of N the merged dataset says shard "0/1", so it equals
//! the single-machine run byte for byte. Their collect reports, when every input has one, are
//! merged into the output's (counts summed, failures concatenated).

use crate::export::bounded::read_json;
use crate::export::collection::{Collection, RecordedShard, Shard};
use crate::export::convert::ConvertError;
use crate::export::error::ExportError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::info::DatasetInfo;
use crate::export::lerobot::options::{LeRobotOptions, LeRobotVersion, VideoOptions};
use crate::export::lerobot::read::LeRobotSource;
use crate::export::lerobot::writer::LeRobotWriter;
pub use crate::export::merge::REPORT;
use crate::export::pipeline::{Episodes, in_order};
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// What of an input's info.json shapes the merged files: all inputs must agree on it.
#[derive(Debug, PartialEq, serde::Serialize)]
struct Layout {
    codebase_version: Option<String>,
    data_files_size_in_mb: Option<u64>,
    video_files_size_in_mb: Option<u64>,
    chunks_size: Option<u64>,
}

impl std::fmt::Display for Layout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match serde_json::to_string(self) {
            Ok(text) => f.write_str(&text),
            Err(_) => write!(f, "{self:?}"),
        }
    }
}

/// One input: its source, its LeRobot layout, and its shard ("I/N") if it says.
struct Input {
    path: PathBuf,
    source: LeRobotSource,
    layout: Layout,
    shard: Option<Shard>,
}

fn open(path: &Path) -> Result<Input, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    if !path.exists() {
        return Err(read(ExportError::NotFound {
            path: path.to_path_buf(),
        }));
    }
    let info_path = path.join("meta/info.json");
    let info = super::read::read_info(&info_path).map_err(read)?;
    let source = LeRobotSource::open(path).map_err(read)?;
    let layout = Layout {
        codebase_version: info.codebase_version,
        data_files_size_in_mb: info.data_files_size_in_mb,
        video_files_size_in_mb: info.video_files_size_in_mb,
        chunks_size: info.chunks_size,
    };
    let shard = source
        .info()
        .collection
        .as_ref()
        .and_then(|c| c.shard()?.part());
    Ok(Input {
        path: path.to_path_buf(),
        source,
        layout,
        shard,
    })
}

/// What differs between two inputs, by name ("fps", "collection.seed", ...).
fn differences(a: &Input, b: &Input) -> Vec<String> {
    let (x, y) = (a.source.info(), b.source.info());
    let mut differ = Vec::new();
    if x.fps != y.fps {
        differ.push(format!("fps {} vs {}", y.fps, x.fps));
    }
    if x.robot_type != y.robot_type {
        differ.push(format!(
            "robot type {:?} vs {:?}",
            y.robot_type, x.robot_type
        ));
    }
    if x.features != y.features {
        differ.push("features".into());
    }
    if x.camera != y.camera {
        differ.push("camera".into());
    }
    if x.mask_ids != y.mask_ids {
        differ.push("mask ids".into());
    }
    if x.generator != y.generator {
        differ.push(format!("generator {:?} vs {:?}", y.generator, x.generator));
    }
    if x.tip_workspace != y.tip_workspace {
        differ.push("tool-tip workspace".into());
    }
    let none = Collection::default();
    let (cx, cy) = (
        x.collection.as_ref().unwrap_or(&none),
        y.collection.as_ref().unwrap_or(&none),
    );
    differ.extend(
        cx.differences(cy)
            .into_iter()
            .map(|(k, vx, vy)| format!("collection option {k} ({vy} vs {vx})")),
    );
    if a.layout != b.layout {
        differ.push(format!("layout {} vs {}", b.layout, a.layout));
    }
    differ
}

/// Refuses inputs that cannot make one dataset with the first, and puts the shards of one
/// collection in shard order (the same shard twice is a mistake).
fn order_inputs(opened: &mut [Input]) -> Result<(), MergeError> {
    let Some(first) = opened.first() else {
        return Err(MergeError::NoInput);
    };
    for input in &opened[1..] {
        let reasons = differences(first, input);
        if !reasons.is_empty() {
            return Err(MergeError::Incompatible {
                path: input.path.clone(),
                first: first.path.clone(),
                reasons: reasons.join("; "),
            });
        }
    }
    if opened.iter().all(|i| i.shard.is_some()) {
        opened.sort_by_key(|i| i.shard.map(|s| (s.index, s.count)));
        for pair in opened.windows(2) {
            if pair[0].shard == pair[1].shard {
                return Err(MergeError::Incompatible {
                    path: pair[1].path.clone(),
                    first: pair[0].path.clone(),
                    reasons: format!(
                        "both are shard \"{}\"",
                        pair[0].shard.map(|s| s.to_string()).unwrap_or_default()
                    ),
                });
            }
        }
    }
    Ok(())
}

/// Records in `info`'s collection which shards were merged: `0/1` when all N of N are, in
/// order (the single run's dataset), else the list.
fn mark_merged_shards(info: &mut crate::export::info::DatasetInfo, opened: &[Input]) {
    let shards: Vec<Shard> = opened.iter().filter_map(|i| i.shard).collect();
    if opened.first().is_some_and(|i| i.shard.is_some())
        && let Some(collection) = &mut info.collection
    {
        let merged = if shards.len() == opened.len() {
            RecordedShard::merged(&shards)
        } else {
            RecordedShard::Merged(shards)
        };
        collection.set_shard(&merged);
    }
}

/// The writer's options of the merged dataset: the first input's layout, its video copied as
/// it is, in its own codec, rolled at the inputs' video file size.
fn merged_options(info: &crate::export::info::DatasetInfo, layout: &Layout) -> LeRobotOptions {
    let video = info
        .features
        .iter()
        .find_map(|f| f.video)
        .map(|codec| VideoOptions {
            codec,
            quality: 0,
            file_size_mb: layout
                .video_files_size_in_mb
                .unwrap_or(VideoOptions::default().file_size_mb),
        });
    LeRobotOptions {
        video,
        version: if layout.codebase_version.as_deref() == Some("v2.1") {
            LeRobotVersion::V21
        } else {
            LeRobotVersion::V30
        },
        data_file_size_mb: layout.data_files_size_in_mb.unwrap_or(100),
        chunks_size: layout.chunks_size.unwrap_or(1000),
        ..LeRobotOptions::default()
    }
}

/// Merges the request's inputs into a new LeRobot dataset at its `out` (see the module
/// overview), on `threads` worker threads (0: one per core), or continues an interrupted merge
/// of the same inputs (`resume`); `progress` hears the episodes done so far.
pub fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let (out, threads, exact_stats) = (request.out, request.threads, request.exact_stats);
    let mut opened: Vec<Input> = request
        .inputs
        .iter()
        .map(|p| open(p))
        .collect::<Result<_, _>>()?;
    order_inputs(&mut opened)?;
    let mut info = opened[0].source.info().clone();
    // What a resume must find again: every input, in order.
    let identities: Vec<String> = opened
        .iter()
        .map(|i| crate::export::identity::of(&i.path))
        .collect::<Result<_, _>>()
        .map_err(|e| MergeError::Convert(ConvertError::Read(e)))?;
    info.input = Some(identities.join("; "));
    mark_merged_shards(&mut info, &opened);
    // The first input's named splits do not describe the merged episodes.
    info.splits = Vec::new();
    let options = merged_options(&info, &opened[0].layout);
    let reports: Option<Vec<Value>> = opened
        .iter()
        .map(|i| read_json(&i.path.join(REPORT)).ok())
        .collect();
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let resuming = crate::export::dir::resumes(out, request.resume);
    let mut sink = LeRobotWriter::open(out, &info, options, resuming).map_err(write)?;
    // A resumed merge skips the episodes already written.
    let sources = opened.iter_mut().map(|i| &mut i.source as _).collect();
    let mut episodes = Episodes::of(sources)
        .renumbered()
        .skipping(sink.next_episode_index());
    let mut write_batch = |mut batch: Vec<crate::episode::Episode>| {
        if exact_stats {
            exact(&mut batch, &info)?;
        }
        sink.write_batch(&batch).map_err(write)
    };
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let progress = &mut *request.progress;
    let pool = crate::threads::pool(threads).map_err(|e| write(e.into()))?;
    pool.install(|| in_order(&mut episodes, read, &mut write_batch, progress))?;
    let shard = info.collection.as_ref().and_then(Collection::shard);
    let summary = match reports {
        Some(reports) => {
            let mut sidecar = |summary: &Summary| {
                crate::export::merge::report_bytes(&reports, summary, shard.as_ref())
                    .map(|file| vec![file])
            };
            sink.finish_with(Some(&mut sidecar))
        }
        None => sink.finish(),
    }
    .map_err(write)?;
    Ok(summary)
}

/// `merge --exact-stats`: each episode's video features get exact statistics from their
/// decoded frames (episodes in parallel).
fn exact(batch: &mut [crate::episode::Episode], info: &DatasetInfo) -> Result<(), MergeError> {
    use rayon::prelude::*;
    batch
        .par_iter_mut()
        .try_for_each(|episode| crate::export::decoded::exact_video_stats(episode, info))
        .map_err(|e| MergeError::Convert(ConvertError::Read(e)))
}
