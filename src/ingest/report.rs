//! What `ingest` says of its synchronisation inside the dataset: one JSON report per input
//! ([`sync_files`]: `meta/sync/<input>.json` in LeRobot, `sync/<input>.json` in the other
//! formats, beside the dataset's own files) and the paragraphs the dataset card gives
//! ([`provenance`]).

use crate::ingest::sync::{OnGap, SyncReport};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// The folder of the reports in a dataset of `format`: LeRobot's metadata folder, else the
/// dataset's top (an RLDS data directory, say).
pub fn sync_dir(format: crate::export::Format) -> &'static str {
    if format.name() == "lerobot" {
        "meta/sync"
    } else {
        "sync"
    }
}

/// One input's report as written.
#[derive(Serialize)]
struct InputReport<'a> {
    /// The input's file or folder name.
    input: &'a str,
    /// The dataset index of its first episode.
    first_episode_index: u64,
    #[serde(flatten)]
    sync: &'a SyncReport,
}

/// A report's file name for `path`: its name with every character but ASCII letters, digits,
/// `-`, `_` and `.` replaced by `_`, then `.json`; a name already taken gets `-2`, `-3`, ...
fn file_name(path: &Path, taken: &mut Vec<String>) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let safe: String = name
        .chars()
        .map(|c| match c {
            'a'..='z' | 'A'..='Z' | '0'..='9' | '-' | '_' | '.' => c,
            _ => '_',
        })
        .collect();
    let safe = match safe.trim_start_matches('.') {
        "" => "input".to_string(),
        trimmed => trimmed.to_string(),
    };
    let mut candidate = safe.clone();
    let mut n = 1;
    while taken.contains(&candidate) {
        n += 1;
        candidate = format!("{safe}-{n}");
    }
    taken.push(candidate.clone());
    format!("{candidate}.json")
}

/// Each input's report: (path relative to the dataset, JSON bytes), in input order.
pub fn sync_files(
    inputs: &[(&Path, &SyncReport)],
    dir: &str,
) -> Result<Vec<(String, Vec<u8>)>, serde_json::Error> {
    let mut taken = Vec::new();
    let mut first_episode_index = 0;
    let mut files = Vec::with_capacity(inputs.len());
    for (path, sync) in inputs {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let report = InputReport {
            input: &name,
            first_episode_index,
            sync,
        };
        let mut bytes = serde_json::to_vec_pretty(&report)?;
        bytes.push(b'\n');
        files.push((format!("{dir}/{}", file_name(path, &mut taken)), bytes));
        first_episode_index += sync.episodes.len() as u64;
    }
    Ok(files)
}

/// The dataset card's account of the synchronisation: the rule, then per input its frames,
/// episodes, frames not written and streams with gaps.
pub fn provenance(inputs: &[(&Path, &SyncReport)]) -> Vec<String> {
    let Some((_, first)) = inputs.first() else {
        return Vec::new();
    };
    let gaps = match first.on_gap {
        OnGap::Split => "a new episode starts after frames that are not written",
        OnGap::Drop => "frames that are not written are left out and the rest numbered on",
    };
    let mut rule = format!(
        "Ingested by surgvla from {} robot recordings. Synchronisation: frames on a uniform grid at {} fps over the span every sampled stream (measured state, cameras) covers; each frame takes, per stream, the latest message at or before it; a frame where a sampled stream's message is more than {} ms old is not written, and {gaps}. Commands hold their last value. Nothing is interpolated. Each input's full report is in the dataset's `sync` folder (LeRobot: `meta/sync/`).",
        inputs.len(),
        first.fps,
        first.tolerance_ms,
    );
    rule.push_str("\n\n| input | episodes | frames | frames not written | streams with gaps |\n|---|---:|---:|---:|---|");
    for (path, report) in inputs {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let frames: usize = report.episodes.iter().sum();
        let gappy: Vec<String> = (report.streams.iter())
            .filter(|s| !s.gaps.is_empty())
            .map(|s| format!("`{}` ({})", s.topic.replace('|', "\\|"), s.gaps.len()))
            .collect();
        let _ = write!(
            rule,
            "\n| `{}` | {} | {frames} | {} | {} |",
            name.replace(['|', '`'], "_"),
            report.episodes.len(),
            report.dropped_frames,
            if gappy.is_empty() {
                "none".to_string()
            } else {
                gappy.join(", ")
            }
        );
    }
    vec![rule]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::sync::{Gap, StreamKind, StreamReport};

    fn report(episodes: Vec<usize>) -> SyncReport {
        SyncReport {
            fps: 30,
            tolerance_ms: 50.0,
            on_gap: OnGap::Split,
            grid: Some((0, 1_000)),
            streams: vec![StreamReport {
                topic: "/camera/left".into(),
                kind: StreamKind::Sampled,
                count: 10,
                rate_hz: 30.0,
                jitter_ms: 0.5,
                gaps: vec![Gap { start: 5, end: 900 }],
                out_of_order: 0,
            }],
            dropped_frames: 3,
            episodes,
        }
    }

    #[test]
    fn one_report_per_input_with_safe_distinct_names() {
        let (a, b) = (report(vec![4, 5]), report(vec![7]));
        let inputs = [
            (Path::new("/data/run 1.bag"), &a),
            (Path::new("/other/run 1.bag"), &b),
            (Path::new("../.."), &b),
        ];
        let files = sync_files(&inputs, "meta/sync").expect("json");
        let names: Vec<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(
            names,
            [
                "meta/sync/run_1.bag.json",
                "meta/sync/run_1.bag-2.json",
                "meta/sync/input.json"
            ]
        );
        let second: serde_json::Value = serde_json::from_slice(&files[1].1).expect("json");
        assert_eq!(second["first_episode_index"], 2);
        assert_eq!(second["input"], "run 1.bag");
        assert_eq!(second["streams"][0]["gaps"][0]["end"], 900);
        assert_eq!(second["dropped_frames"], 3);
        let card = provenance(&inputs).join("\n");
        assert!(
            card.contains("at 30 fps") && card.contains("50 ms old"),
            "{card}"
        );
        assert!(
            card.contains("| `run 1.bag` | 2 | 9 | 3 | `/camera/left` (1) |"),
            "{card}"
        );
    }
}
