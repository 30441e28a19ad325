//! The metadata files of a LeRobot dataset: the tasks table (with its pandas index), the
//! episodes table (v3.0 parquet or v2.1 JSON lines), `stats.json` against the data, and the
//! video files' spans.

use super::parts::{
    Declared, EpisodeEntry, Moments, Part, STATS_KEYS, is_index_column, read_table,
};
use crate::error::ErrorKind;
use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::findings::{At, Findings};
use crate::export::lerobot::meta::{FeatureStatsJson, StatValue, StatsJson};
use crate::export::lint::cameras::{CameraFrames, FrameLook};
use crate::export::paths;
use crate::media::demux::VideoReader;
use arrow_array::{Array, BooleanArray, Float64Array, Int64Array, ListArray, StringArray};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The tasks, by task_index.
pub(super) fn read_tasks(root: &Path, v21: bool, findings: &Findings) -> Vec<String> {
    let relative = if v21 {
        "meta/tasks.jsonl"
    } else {
        "meta/tasks.parquet"
    };
    let path = root.join(relative);
    if !path.is_file() {
        findings.file_error(&path, Check::Present, "is missing");
        return Vec::new();
    }
    let tasks = if v21 {
        read_tasks_v21(&path, findings)
    } else {
        read_tasks_v30(&path, findings)
    };
    for (position, (index, task)) in tasks.iter().enumerate() {
        if *index != position as i64 {
            findings.file_error(
                &path,
                Check::Tasks,
                format!(
                    "row {position} has task_index {index}; task indices must be 0..n in order"
                ),
            );
        }
        if task.trim().is_empty() {
            findings.file_error(
                &path,
                Check::Instruction,
                format!("task {index} is an empty language instruction"),
            );
        }
    }
    tasks.into_iter().map(|(_, t)| t).collect()
}

/// The non-blank lines of a JSON-lines file, read one bounded line at a time
/// ([`crate::export::bounded::lines`]); what stops the reading is a finding of `check`.
fn bounded_lines(
    path: &Path,
    check: Check,
    findings: &Findings,
) -> impl Iterator<Item = (usize, String)> {
    let lines = match crate::export::bounded::lines(path) {
        Ok(lines) => Some(lines),
        Err(error) => {
            findings.file_error(
                path,
                check,
                format!("cannot be read: {}", error_text(&error)),
            );
            None
        }
    };
    lines
        .into_iter()
        .flatten()
        .map_while(move |line| match line {
            Ok(line) => Some(line),
            Err(error) => {
                findings.file_error(path, check, error_text(&error));
                None
            }
        })
}

/// An error's own problem, without the path a finding already names.
fn error_text(error: &crate::export::error::ExportError) -> String {
    match error {
        crate::export::error::ExportError::InvalidDataset { problem, .. } => problem.clone(),
        crate::export::error::ExportError::Io { source, .. } => source.to_string(),
        other => other.to_string(),
    }
}

/// v2.1's `meta/tasks.jsonl`: (task_index, task) per line.
fn read_tasks_v21(path: &Path, findings: &Findings) -> Vec<(i64, String)> {
    use crate::export::lerobot::meta::TaskLine;
    let mut tasks = Vec::new();
    for line in bounded_lines(path, Check::Readable, findings) {
        let (line_number, line) = line;
        match TaskLine::of(&line) {
            TaskLine {
                task_index: Some(index),
                task: Some(task),
            } => tasks.push((index, task)),
            _ => findings.file_error(
                path,
                Check::Tasks,
                format!("line {line_number} lacks task_index or task"),
            ),
        }
    }
    tasks
}

/// v3.0's `meta/tasks.parquet`: (task_index, task) per row, and the pandas metadata that makes
/// lerobot index the table by task.
fn read_tasks_v30(path: &Path, findings: &Findings) -> Vec<(i64, String)> {
    match crate::export::lerobot::read::schema_metadata(path, "pandas") {
        Ok(Some(pandas)) => {
            let pandas: Value = serde_json::from_str(&pandas).unwrap_or(Value::Null);
            if pandas["index_columns"] != serde_json::json!(["task"]) {
                findings.file_error(
                    path,
                    Check::Tasks,
                    "the pandas metadata does not index by \"task\" (lerobot then returns task indices as the task)",
                );
            }
        }
        _ => findings.file_error(
            path,
            Check::Tasks,
            "has no pandas schema metadata with index_columns [\"task\"] (lerobot then returns task indices as the task)",
        ),
    }
    let mut tasks = Vec::new();
    for batch in read_table(path, findings).unwrap_or_default() {
        let index = batch
            .column_by_name("task_index")
            .and_then(|c| c.as_any().downcast_ref::<Int64Array>());
        let task = batch
            .column_by_name("task")
            .and_then(|c| c.as_any().downcast_ref::<StringArray>());
        let (Some(index), Some(task)) = (index, task) else {
            findings.file_error(
                path,
                Check::Tasks,
                "lacks an int64 task_index or a string task column",
            );
            break;
        };
        for row in 0..batch.num_rows() {
            tasks.push((index.value(row), task.value(row).to_string()));
        }
    }
    tasks
}

/// The episodes metadata, in row order.
/// `as_written`: a dataset surgvla wrote, unedited since, whose episodes table must hold
/// everything our writer writes.
pub(super) fn read_episodes(
    root: &Path,
    v21: bool,
    features: &[Declared],
    as_written: bool,
    findings: &Findings,
) -> Vec<EpisodeEntry> {
    if v21 {
        read_episodes_v21(root, findings)
    } else {
        read_episodes_v30(root, features, as_written, findings)
    }
}

/// v2.1's `meta/episodes.jsonl` (lines in episode order) and `episodes_stats.jsonl` (a line per
/// episode).
fn read_episodes_v21(root: &Path, findings: &Findings) -> Vec<EpisodeEntry> {
    let mut entries = Vec::new();
    let path = root.join("meta/episodes.jsonl");
    if !path.is_file() {
        findings.file_error(&path, Check::Present, "is missing or unreadable");
        return entries;
    }
    for (row, (_, line)) in bounded_lines(&path, Check::Episodes, findings).enumerate() {
        let value: Value = serde_json::from_str(&line).unwrap_or(Value::Null);
        if value["episode_index"].as_i64() != Some(row as i64) {
            findings.error(
                At::file("meta/episodes.jsonl").episode(row as u64),
                Check::Episodes,
                format!(
                    "line {} has episode_index {}; lines must be in episode order",
                    row + 1,
                    value["episode_index"]
                ),
            );
        }
        let mut entry = EpisodeEntry {
            length: value["length"].as_i64(),
            tasks: value["tasks"]
                .as_array()
                .map(|t| {
                    t.iter()
                        .filter_map(|v| v.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default(),
            ..EpisodeEntry::default()
        };
        if let Some(object) = value.as_object() {
            for (key, v) in object.iter().filter(|(k, _)| k.starts_with("surgvla/")) {
                entry.provenance.insert(key.clone(), v.clone());
            }
        }
        entries.push(entry);
    }
    let stats_path = root.join("meta/episodes_stats.jsonl");
    match stats_path.is_file() {
        true => {
            let lines = bounded_lines(&stats_path, Check::Stats, findings).count();
            if lines != entries.len() {
                findings.file_error(
                    &stats_path,
                    Check::Stats,
                    format!("has {lines} lines for {} episodes", entries.len()),
                );
            }
        }
        false => findings.file_error(&stats_path, Check::Stats, "is missing"),
    }
    entries
}

/// v3.0's episodes table (`meta/episodes/chunk-*/file-*.parquet`): rows in episode order, with
/// their spans, data and video files, tasks and provenance.
fn read_episodes_v30(
    root: &Path,
    features: &[Declared],
    as_written: bool,
    findings: &Findings,
) -> Vec<EpisodeEntry> {
    let mut entries = Vec::new();
    let folder = root.join("meta/episodes");
    let files = crate::export::lerobot::read::parquet_files(&folder).unwrap_or_default();
    if files.is_empty() {
        findings.error(
            At::file("meta/episodes"),
            Check::Present,
            "no episodes table (meta/episodes/chunk-*/file-*.parquet)",
        );
    }
    for path in files {
        for batch in read_table(&path, findings).unwrap_or_default() {
            check_episode_columns(&batch, &path, features, as_written, findings);
            for row in 0..batch.num_rows() {
                let at = At::file(findings.relative(&path)).episode(entries.len() as u64);
                entries.push(episode_entry(&batch, row, at, features, findings));
            }
        }
    }
    entries
}

/// Row `row` of an episodes table, which must be the episode `at` names.
fn episode_entry(
    batch: &arrow_array::RecordBatch,
    row: usize,
    at: At,
    features: &[Declared],
    findings: &Findings,
) -> EpisodeEntry {
    let column = |name: &str| batch.column_by_name(name).map(|c| c.as_any());
    let get = |name: &str| {
        column(name)
            .and_then(|c| c.downcast_ref::<Int64Array>())
            .map(|c| c.value(row))
    };
    let float = |name: &str| {
        column(name)
            .and_then(|c| c.downcast_ref::<Float64Array>())
            .map(|c| c.value(row))
    };
    let position = at.episode.unwrap_or_default() as i64;
    if let Some(index) = get("episode_index")
        && index != position
    {
        findings.error(
            at.clone(),
            Check::Episodes,
            format!("row {position} has episode_index {index}; lerobot looks episodes up by row"),
        );
    }
    let mut entry = EpisodeEntry {
        length: get("length"),
        from: get("dataset_from_index"),
        to: get("dataset_to_index"),
        data_file: get("data/chunk_index").zip(get("data/file_index")),
        ..EpisodeEntry::default()
    };
    let tasks = column("tasks").and_then(|c| c.downcast_ref::<ListArray>());
    if let Some(tasks) = tasks {
        let list = tasks.value(row);
        if let Some(strings) = list.as_any().downcast_ref::<StringArray>() {
            entry.tasks = strings.iter().flatten().map(String::from).collect();
        }
    }
    for feature in features.iter().filter(|f| f.dtype == "video") {
        let key = &feature.name;
        let chunk = get(&format!("videos/{key}/chunk_index"));
        let file = get(&format!("videos/{key}/file_index"));
        let from = float(&format!("videos/{key}/from_timestamp"));
        let to = float(&format!("videos/{key}/to_timestamp"));
        // surgvla's exact statistics accumulator of the episode's frames, if present.
        let pixel_stats = format!("surgvla/pixel_stats/{key}");
        if let Some(text) = column(&pixel_stats)
            .and_then(|c| c.downcast_ref::<StringArray>())
            .filter(|c| c.is_valid(row))
        {
            entry
                .provenance
                .insert(pixel_stats, Value::from(text.value(row)));
        }
        match (chunk, file, from, to) {
            (Some(c), Some(f), Some(from), Some(to)) => {
                entry.videos.insert(key.clone(), (c, f, from, to));
            }
            _ => findings.error(
                at.clone(),
                Check::Videos,
                format!("lacks the videos/{key}/... columns of the video feature"),
            ),
        }
    }
    for key in crate::export::lerobot::table::Provenance::KEYS {
        let Some(any) = column(key) else {
            continue;
        };
        let value = if let Some(a) = any.downcast_ref::<Int64Array>() {
            Value::from(a.value(row))
        } else if let Some(a) = any.downcast_ref::<StringArray>() {
            Value::from(a.value(row))
        } else if let Some(a) = any.downcast_ref::<BooleanArray>() {
            Value::from(a.value(row))
        } else {
            Value::Null
        };
        entry.provenance.insert(key.to_string(), value);
    }
    entry
}

/// The columns an episodes table needs: indices and spans, tasks, and every statistic of every
/// feature. Tasks and per-episode statistics are errors to lack only `as_written` (surgvla's
/// writer writes them); lerobot's own tools may leave them out (its `convert_image_to_video`
/// does, and its loader needs neither): a warning each.
fn check_episode_columns(
    batch: &arrow_array::RecordBatch,
    path: &Path,
    features: &[Declared],
    as_written: bool,
    findings: &Findings,
) {
    let ints = |name: &str| {
        batch
            .column_by_name(name)
            .and_then(|c| c.as_any().downcast_ref::<Int64Array>())
    };
    for required in [
        "episode_index",
        "length",
        "dataset_from_index",
        "dataset_to_index",
        "data/chunk_index",
        "data/file_index",
    ] {
        if ints(required).is_none() {
            findings.file_error(
                path,
                Check::Episodes,
                format!("lacks the int64 column {required}"),
            );
        }
    }
    let at = || At::file(findings.relative(path));
    if batch.column_by_name("tasks").is_none() {
        let message = "lacks the tasks column";
        match as_written {
            true => findings.error(at(), Check::Episodes, message),
            false => findings.warning(
                at(),
                Check::Episodes,
                format!("{message} (each frame's task_index still names its task)"),
            ),
        }
    }
    let missing: Vec<String> = (features.iter())
        .filter(|f| !is_index_column(&f.name) && f.dtype != "string")
        .flat_map(|f| STATS_KEYS.map(|stat| format!("stats/{}/{stat}", f.name)))
        .filter(|name| batch.column_by_name(name).is_none())
        .collect();
    if as_written {
        for name in &missing {
            findings.error(at(), Check::Stats, format!("lacks the column {name}"));
        }
    } else if !missing.is_empty() {
        findings.warning(
            at(),
            Check::Stats,
            format!(
                "has no per-episode statistics for {} columns (e.g. {}): meta/stats.json holds the dataset's",
                missing.len(),
                missing[0]
            ),
        );
    }
}

/// `meta/stats.json`: every feature with every statistic, vectors of the right length, and for
/// numeric features min, max and mean matching the data (quick or not: every row's numbers are
/// read).
pub(super) fn check_stats(
    root: &Path,
    features: &[Declared],
    parts: &[Part],
    as_written: bool,
    findings: &Findings,
) {
    let path = root.join("meta/stats.json");
    // v2.1 as lerobot (0.3.x) writes it: per-episode statistics only, which its loader
    // aggregates (their lines are checked with the episodes).
    if !path.is_file() && root.join("meta/episodes_stats.jsonl").is_file() {
        return;
    }
    if !path.is_file() {
        findings.file_error(&path, Check::Stats, "is missing (normalisation needs it)");
        return;
    }
    let Ok(stats) = read_json(&path) else {
        findings.file_error(&path, Check::Stats, "is not valid JSON");
        return;
    };
    // Leniently typed: a feature whose entry is not an object has no statistics.
    let stats: StatsJson = stats
        .as_object()
        .into_iter()
        .flatten()
        .filter(|(_, entry)| entry.is_object())
        .map(|(name, entry)| (name.clone(), FeatureStatsJson::from_value(entry.clone())))
        .collect();
    let data = data_moments(parts);
    for feature in features
        .iter()
        .filter(|f| !is_index_column(&f.name) && f.dtype != "string")
    {
        let Some(entry) = stats.get(&feature.name) else {
            let message = format!("has no statistics for {}", feature.name);
            match as_written {
                true => findings.file_error(&path, Check::Stats, message),
                // lerobot's convert_image_to_video leaves the images' out.
                false => findings.warning(
                    At::file(findings.relative(&path)),
                    Check::Stats,
                    format!("{message} (a policy that normalises it needs them: lerobot-edit-dataset's recompute_stats writes them)"),
                ),
            }
            continue;
        };
        // A statistic that is not numbers (or nested lists of them) counts as missing.
        for key in STATS_KEYS {
            if entry.get(key).is_none() {
                findings.file_error(&path, Check::Stats, format!("{} lacks {key}", feature.name));
            }
        }
        let numeric = matches!(feature.dtype.as_str(), "float32" | "float64");
        if !numeric {
            continue;
        }
        check_stat_lengths(&path, feature, entry, findings);
        if let Some(moments) = data.get(feature.name.as_str()) {
            check_stats_against_data(&path, feature, entry, moments, findings);
        }
    }
}

/// Per feature, the data's moments over every part.
fn data_moments(parts: &[Part]) -> BTreeMap<&str, Moments> {
    let mut data: BTreeMap<&str, Moments> = BTreeMap::new();
    for part in parts {
        for (name, moments) in &part.moments {
            let total = data
                .entry(name.as_str())
                .or_insert_with(|| vec![(f64::INFINITY, f64::NEG_INFINITY, 0.0, 0); moments.len()]);
            for (t, m) in total.iter_mut().zip(moments) {
                *t = (t.0.min(m.0), t.1.max(m.1), t.2 + m.2, t.3 + m.3);
            }
        }
    }
    data
}

/// A numeric feature's statistics hold one value per element.
fn check_stat_lengths(
    path: &Path,
    feature: &Declared,
    entry: &FeatureStatsJson,
    findings: &Findings,
) {
    let n = feature.elements();
    for key in ["min", "max", "mean", "std", "q01", "q50", "q99"] {
        if let Some(len) = entry.get(key).and_then(StatValue::list_len)
            && len != n
        {
            findings.file_error(
                path,
                Check::Stats,
                format!(
                    "{}.{key} has {len} values for shape {:?}",
                    feature.name, feature.shape
                ),
            );
        }
    }
}

/// A numeric feature's min, max and mean agree with the data's.
fn check_stats_against_data(
    path: &Path,
    feature: &Declared,
    entry: &FeatureStatsJson,
    moments: &Moments,
    findings: &Findings,
) {
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-4 * (1.0 + a.abs().max(b.abs()));
    for (i, &(min, max, sum, count)) in moments.iter().enumerate() {
        let mean = sum / count.max(1) as f64;
        for (key, value) in [("min", min), ("max", max), ("mean", mean)] {
            let Some(stat) = entry.get(key).and_then(|s| s.element(i)) else {
                continue;
            };
            if !close(stat, value) {
                findings.file_error(
                    path,
                    Check::Stats,
                    format!(
                        "{}.{key}[{i}] is {stat}, the data gives {value}",
                        feature.name
                    ),
                );
            }
        }
    }
}

/// A video file's sample tables, or why they cannot be read (and whether that is a codec
/// surgvla does not read rather than a defect).
fn open_video(path: &Path) -> Result<Arc<VideoReader>, (String, bool)> {
    VideoReader::open(path).map(Arc::new).map_err(|e| {
        let unsupported = crate::error::HasKind::kind(&e) == ErrorKind::Usage;
        match e {
            crate::media::MediaError::Invalid { problem, .. } => (problem, unsupported),
            other => (other.to_string(), unsupported),
        }
    })
}

/// Episode `i`'s video file of `key` (relative) and its span there (v2.1: the whole file);
/// `None` when the episodes table gives the episode no span of it.
fn episode_video(
    v21: bool,
    chunks_size: i64,
    key: &str,
    i: usize,
    entry: &EpisodeEntry,
) -> Option<(String, Option<(f64, f64)>)> {
    if v21 {
        let i = i as i64;
        let chunk = i / chunks_size;
        return Some((
            format!("videos/chunk-{chunk:03}/{key}/episode_{i:06}.mp4"),
            None,
        ));
    }
    let &(chunk, file, from, to) = entry.videos.get(key)?;
    let relative = crate::export::lerobot::layout::video_path(key, chunk as u64, file as u64);
    Some((relative, Some((from, to))))
}

/// Every video feature's files and episode spans: through the MP4 sample tables, each file
/// readable with its samples inside it, in the declared codec and frame size, and each
/// episode's span holding exactly its frames and starting on a keyframe (v2.1: each episode's
/// file holds its frames); then each span decoded (`quick`: each file's first frame only), one
/// episode per worker: every sample decodes, to the declared frame size. A codec or profile
/// surgvla does not decode is a warning.
pub(super) fn check_videos(
    root: &Path,
    v21: bool,
    info: &crate::export::lerobot::meta::InfoJson,
    features: &[Declared],
    entries: &[EpisodeEntry],
    (quick, as_written, lint): (bool, bool, bool),
    findings: &Findings,
) -> Vec<CameraFrames> {
    let chunks_size = info.chunks_size.unwrap_or(1000).max(1) as i64;
    let declared: BTreeMap<String, crate::export::lerobot::meta::FeatureJson> =
        info.feature_list().into_iter().collect();
    let mut readers: BTreeMap<PathBuf, Result<Arc<VideoReader>, (String, bool)>> = BTreeMap::new();
    let mut spans: Vec<SpanToDecode> = Vec::new();
    check_templates(info, findings);
    for feature in features.iter().filter(|f| f.dtype == "video") {
        let key = &feature.name;
        if let Err(problem) = paths::component(key) {
            findings.error(
                At::file("meta/info.json"),
                Check::Paths,
                format!("the video feature {key:?} cannot name a folder: it {problem}"),
            );
            continue;
        }
        let size_px = match feature.shape.as_slice() {
            [h, w, _] => Some((*w, *h)),
            _ => None,
        };
        let declared_name = declared.get(key).and_then(|f| f.video_codec());
        for (i, entry) in entries.iter().enumerate() {
            let Some((relative, span)) = episode_video(v21, chunks_size, key, i, entry) else {
                continue;
            };
            let path = root.join(&relative);
            let at = At::file(relative).episode(i as u64);
            if !path.is_file() {
                findings.error(at, Check::Present, "is missing");
                continue;
            }
            let fresh = !readers.contains_key(&path);
            let reader = readers
                .entry(path.clone())
                .or_insert_with(|| open_video(&path));
            match reader {
                Ok(reader) => {
                    if fresh {
                        check_video_file(&at, reader, feature, declared_name, findings);
                    }
                    let length = entry.length;
                    check_episode_span(&at, reader, (span, length), as_written, findings);
                    // Quick: each file's first frame (as lerobot-doctor opens), the spans of
                    // every episode checked above through the sample tables.
                    if let Some(size_px) = size_px.filter(|_| fresh || !quick) {
                        spans.push(SpanToDecode {
                            key: key.clone(),
                            channels: feature.shape.get(2).copied().unwrap_or(3),
                            video: Arc::clone(reader),
                            file: at.file.clone().unwrap_or_default(),
                            episode: i as u64,
                            span,
                            size_px,
                            stored_mean: entry
                                .provenance
                                .get(&format!("surgvla/pixel_stats/{key}"))
                                .and_then(stored_mean),
                        });
                    }
                }
                Err((problem, true)) if fresh => findings.warning(
                    at,
                    Check::VideoDecode,
                    format!("{key}: {problem}; its frames are not checked"),
                ),
                Err((problem, false)) if fresh => findings.error(at, Check::Video, problem.clone()),
                Err(_) => {}
            }
        }
    }
    decode_spans(&spans, (quick, lint), findings)
}

/// An episode's span of a video file, for [`decode_spans`].
struct SpanToDecode {
    /// The video feature.
    key: String,
    /// Its declared channels.
    channels: usize,
    /// The file's reader, its tables shared by every episode in it.
    video: Arc<VideoReader>,
    /// The file as findings name it (relative to the dataset).
    file: String,
    episode: u64,
    /// Seconds (None: the whole file, v2.1).
    span: Option<(f64, f64)>,
    /// The declared (width, height).
    size_px: (usize, usize),
    /// The mean per channel of surgvla's exact statistics accumulator for this episode
    /// (computed from the pixels before encoding), if the episodes table has one.
    stored_mean: Option<[f64; 3]>,
}

/// How far (0..1) the decoded frames' mean per channel may lie from the statistics surgvla
/// stored from the pixels before encoding them: lossy coding moves it by a level or less; a
/// wrong video or wrong statistics move it by far more.
pub(crate) const PIXEL_MEAN_TOLERANCE: f64 = 0.02;

/// The per-channel mean of an exact statistics accumulator (`surgvla/pixel_stats/<key>`: JSON
/// text, or an object).
fn stored_mean(value: &serde_json::Value) -> Option<[f64; 3]> {
    let parsed: crate::export::stats::ImageStats = match value {
        serde_json::Value::String(text) => serde_json::from_str(text).ok()?,
        other => serde_json::from_value(other.clone()).ok()?,
    };
    let json = parsed.to_json();
    let means: Vec<f64> = json["mean"]
        .as_array()?
        .iter()
        .filter_map(|c| c[0][0].as_f64())
        .collect();
    <[f64; 3]>::try_from(means).ok()
}

/// Decodes each episode's span (the first frame only when `quick`), in parallel: a sample that
/// does not decode, or decodes to another size than declared, is a finding naming the file,
/// episode and frame; what surgvla cannot decode (a profile) is a warning, once per file. With
/// `lint` (and not `quick`), returns the lint's look at every decoded frame (its luma).
fn decode_spans(
    spans: &[SpanToDecode],
    (quick, lint): (bool, bool),
    findings: &Findings,
) -> Vec<CameraFrames> {
    use rayon::prelude::*;
    let warned = std::sync::Mutex::new(std::collections::BTreeSet::new());
    let lint = lint && !quick;
    spans.par_iter().map(|to_decode| {
        let SpanToDecode {
            key,
            channels,
            video,
            file,
            episode,
            span,
            size_px,
            stored_mean,
        } = to_decode;
        let mut looks = Vec::new();
        {
            let mut look = |picture: &crate::media::decode::YuvFrame| {
                if lint && !crate::export::lint::cameras::is_mask(key) {
                    let (w, h) = (picture.width_px as usize, picture.height_px as usize);
                    looks.push(FrameLook::of(looks.len() as u64, w, h, 1, &picture.y));
                }
            };
            let (problems, decoded_mean) = crate::media::decode::check::check_span(
                video,
                *span,
                *size_px,
                quick,
                stored_mean.is_some() && !quick,
                &mut look,
            );
            if let (Some(stored), Some(decoded)) = (stored_mean, decoded_mean)
                && stored
                    .iter()
                    .zip(&decoded)
                    .any(|(s, d)| (s - d).abs() > PIXEL_MEAN_TOLERANCE)
            {
                findings.error(
                    At::file(file.clone()).episode(*episode),
                    Check::VideoStats,
                    format!(
                        "the decoded frames' mean RGB is {decoded:.4?}; the episode's stored statistics say {stored:.4?} (more than {PIXEL_MEAN_TOLERANCE} apart)"
                    ),
                );
            }
            for problem in problems {
                let mut at = At::file(file.clone()).episode(*episode);
                if let Some(frame) = problem.frame {
                    at = at.frame(frame);
                }
                if problem.unsupported {
                    let first = warned
                        .lock()
                        .map(|mut w| w.insert(file.clone()))
                        .unwrap_or(false);
                    if first {
                        findings.warning(
                            At::file(file.clone()),
                            Check::VideoDecode,
                            format!("{}; its frames are not checked", problem.message),
                        );
                    }
                } else {
                    findings.error(at, Check::VideoDecode, problem.message);
                }
            }
        }
        CameraFrames {
            episode: *episode,
            camera: key.clone(),
            shape: (size_px.0, size_px.1, *channels),
            frames: looks,
        }
    })
    .filter(|camera| !camera.frames.is_empty())
    .collect()
}

/// info.json's `data_path` and `video_path` templates
/// ([`crate::export::lerobot::meta::InfoJson::template_problem`]).
fn check_templates(info: &crate::export::lerobot::meta::InfoJson, findings: &Findings) {
    if let Some(problem) = info.template_problem() {
        findings.error(At::file("meta/info.json"), Check::Paths, problem);
    }
}

/// A video file, once: in the declared codec and of the declared frame size.
fn check_video_file(
    at: &At,
    reader: &VideoReader,
    feature: &Declared,
    declared_name: Option<&str>,
    findings: &Findings,
) {
    let declared_codec = declared_name.and_then(crate::episode::VideoCodec::from_name);
    if declared_codec.is_some_and(|c| c != reader.codec) {
        findings.error(
            at.clone(),
            Check::Video,
            format!(
                "holds {} video where info.json declares {:?}",
                reader.codec.name(),
                declared_name.unwrap_or_default()
            ),
        );
    }
    let size = [reader.height_px as usize, reader.width_px as usize];
    if feature.shape.len() == 3 && feature.shape[..2] != size {
        findings.error(
            at.clone(),
            Check::Video,
            format!(
                "holds {}x{} frames where {} is declared {:?}",
                size[1], size[0], feature.name, feature.shape
            ),
        );
    }
}

/// An episode's span of a video file (v2.1: the whole file) holds exactly its frames and starts
/// on a keyframe.
/// A later keyframe is a defect of a dataset `as_written` by surgvla (every episode of ours
/// starts on one) and a warning in others' (lerobot's loader decodes from the keyframe before,
/// as does surgvla's; only a stream copy cannot cut there).
fn check_episode_span(
    at: &At,
    reader: &VideoReader,
    (span, length): (Option<(f64, f64)>, Option<i64>),
    as_written: bool,
    findings: &Findings,
) {
    let (frames, keyframe_first) = match span {
        Some((from, to)) => reader.count_span(from, to),
        None => reader.count_span(f64::NEG_INFINITY, f64::INFINITY),
    };
    let Some(length) = length else {
        return;
    };
    if frames as i64 != length {
        let place = match span {
            Some((from, to)) => format!("the span {from}..{to} s holds"),
            None => "holds".into(),
        };
        findings.error(
            at.clone(),
            Check::Video,
            format!("{place} {frames} frames; the episode has {length}"),
        );
    } else if !keyframe_first && as_written {
        findings.error(
            at.clone(),
            Check::Video,
            "the episode's first frame is not a keyframe: it cannot be decoded or copied on its own",
        );
    } else if !keyframe_first {
        findings.warning(
            at.clone(),
            Check::Video,
            "the episode's first frame is not a keyframe: decoding starts at the keyframe before it, and a stream copy cannot cut here",
        );
    }
}
