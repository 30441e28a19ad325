//! What Open-H-Embodiment asks of a contribution besides the LeRobot 2.1 files
//! (`ingest --profile open-h`): `meta/README.md` following Open-H's dataset template, with what
//! the recordings state filled in (episodes, hours, robot, arms, cameras with their sizes and
//! measured rates, the state and action dimensions, the task) and the synchronisation section
//! written from the reports; what only the contributor knows (data type, operators, collection
//! period, attribution) stays the template's placeholder for them to fill.

use crate::episode::Dtype;
use crate::export::info::DatasetInfo;
use crate::ingest::dvrk::DvrkPreset;
use crate::ingest::sync::{OnGap, SyncReport};
use std::fmt::Write as _;
use std::path::Path;

/// Where the README goes in the dataset.
pub const README_PATH: &str = "meta/README.md";

/// What the README is written from.
pub struct ReadmeFacts<'a> {
    /// The dataset's name (its folder's).
    pub name: &'a str,
    pub info: &'a DatasetInfo,
    pub preset: &'a DvrkPreset,
    /// The task given (`--task`); None: the recordings' instruction topic.
    pub task: Option<&'a str>,
    pub reports: &'a [(&'a Path, &'a SyncReport)],
}

/// A Markdown cell's text: no pipes, backticks or line breaks.
fn cell(text: &str) -> String {
    text.replace(['|', '`', '\n', '\r'], " ")
}

/// The measured rate of `topic` over the inputs, by message count and span (Hz).
fn rate_hz(reports: &[(&Path, &SyncReport)], topic: &str) -> Option<f64> {
    let rates: Vec<f64> = (reports.iter())
        .flat_map(|(_, r)| r.streams.iter())
        .filter(|s| s.topic == topic && s.rate_hz > 0.0)
        .map(|s| s.rate_hz)
        .collect();
    (!rates.is_empty()).then(|| rates.iter().sum::<f64>() / rates.len() as f64)
}

/// Open-H's dataset template with `{key}` slots for what the recordings state.
const TEMPLATE: &str = include_str!("openh_readme.md");

/// `meta/README.md` (see the module overview).
pub fn readme(facts: &ReadmeFacts) -> String {
    let ReadmeFacts {
        name,
        info,
        preset,
        task,
        reports,
    } = facts;
    let episodes: usize = reports.iter().map(|(_, r)| r.episodes.len()).sum();
    let frames: usize = (reports.iter()).flat_map(|(_, r)| r.episodes.iter()).sum();
    let hours = frames as f64 / f64::from(info.fps.max(1)) / 3600.0;
    let task_line = match task {
        Some(task) => format!("`{}`", cell(task)),
        None => "the recordings' `/instruction` topic (each frame's in `instruction.text`; every task in `meta/tasks.jsonl`)".into(),
    };
    let slots = [
        ("{name}", cell(name)),
        ("{arms}", preset.arms.join(", ")),
        ("{cameras}", preset.cameras.len().to_string()),
        ("{fps}", info.fps.to_string()),
        ("{task_line}", task_line),
        ("{episodes}", episodes.to_string()),
        ("{hours}", format!("{hours:.3}")),
        ("{splits}", splits(info)),
        ("{camera_rows}", camera_rows(info, preset, reports)),
        ("{action}", dimensions(info, "action", "commanded")),
        ("{state}", dimensions(info, "observation.state", "measured")),
        ("{sync}", synchronisation(info, reports)),
    ];
    // One pass over the template, so a value holding a slot's name is not filled again.
    let mut out = String::with_capacity(TEMPLATE.len() * 2);
    let mut rest = TEMPLATE;
    while let Some(at) = rest.find('{') {
        out.push_str(&rest[..at]);
        rest = &rest[at..];
        match slots.iter().find(|(slot, _)| rest.starts_with(slot)) {
            Some((slot, value)) => {
                out.push_str(value);
                rest = &rest[slot.len()..];
            }
            None => {
                out.push('{');
                rest = &rest[1..];
            }
        }
    }
    out.push_str(rest);
    out
}

/// The Sensors & Cameras rows: each camera's topic, size and measured rate.
fn camera_rows(
    info: &DatasetInfo,
    preset: &DvrkPreset,
    reports: &[(&Path, &SyncReport)],
) -> String {
    let mut out = String::new();
    for (camera, topic) in &preset.cameras {
        let size = (info.features.iter())
            .find(|f| f.name == format!("observation.images.{camera}"))
            .map(|f| {
                format!(
                    "{}x{}",
                    f.shape.get(1).unwrap_or(&0),
                    f.shape.first().unwrap_or(&0)
                )
            })
            .unwrap_or_default();
        let rate =
            rate_hz(reports, topic).map_or(String::new(), |hz| format!(" @ {hz:.1} Hz measured"));
        let _ = writeln!(
            out,
            "| **Camera `{}`** | ROS topic `{}`, {size}{rate} `[model]` |",
            cell(camera),
            cell(topic)
        );
    }
    out
}

/// A vector feature's dimensions as the template lists them.
fn dimensions(info: &DatasetInfo, feature: &str, what: &str) -> String {
    let names = (info.features.iter())
        .find(|f| f.name == feature && f.dtype == Dtype::Float32)
        .map(|f| f.names.join(", "))
        .unwrap_or_default();
    format!(
        "```\n{feature}: [{names}]\n- x, y, z: {what} tool-tip position of each arm (metres)\n- qx, qy, qz, qw: its orientation as a unit quaternion\n- jaw: jaw angle (radians)\n```"
    )
}

/// The `splits` as the README lists them.
fn splits(info: &DatasetInfo) -> String {
    if info.splits.is_empty() {
        return "`train` (every episode; give `--split` to name others)".into();
    }
    (info.splits.iter())
        .map(|(name, range)| format!("`{}` {}:{}", cell(name), range.start, range.end))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The synchronisation section: the rule, then per input its streams as measured.
fn synchronisation(info: &DatasetInfo, reports: &[(&Path, &SyncReport)]) -> String {
    let Some((_, first)) = reports.first() else {
        return String::new();
    };
    let gaps = match first.on_gap {
        OnGap::Split => {
            "after frames that are not written, a new episode starts, so every episode is continuous"
        }
        OnGap::Drop => {
            "frames that are not written are left out and the rest numbered on (timestamps k / fps)"
        }
    };
    let mut out = format!(
        "Every message is placed at its ROS `header.stamp` (or the recorder's receive time where stated), shifted by any per-topic offset given. Frames lie on a uniform grid at {fps} fps from the latest first message to the earliest last message of the sampled streams (measured kinematics and cameras). Each frame takes, per stream, the message with the greatest stamp at or before it (ties: the later one in the recording). A frame where a sampled stream's message is more than {tolerance} ms old is not written; {gaps}. Commands (setpoints) and the instruction are events and hold their last value. Nothing is interpolated. Each episode's timestamps start at 0 (frame index / fps). The per-input reports, with every stream's rate, jitter, gaps and out-of-order stamps, are in `meta/sync/`.\n\n| input | stream | messages | rate (Hz) | jitter (ms) | gaps | out of order |\n| :--- | :--- | ---: | ---: | ---: | ---: | ---: |\n",
        fps = info.fps,
        tolerance = first.tolerance_ms,
    );
    for (path, report) in reports {
        let input = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        for stream in &report.streams {
            let _ = writeln!(
                out,
                "| `{}` | `{}` | {} | {:.1} | {:.2} | {} | {} |",
                cell(&input),
                cell(&stream.topic),
                stream.count,
                stream.rate_hz,
                stream.jitter_ms,
                stream.gaps.len(),
                stream.out_of_order
            );
        }
    }
    out.push_str(
        "\n| input | episodes | frames | grid times not written |\n| :--- | ---: | ---: | ---: |\n",
    );
    for (path, report) in reports {
        let input = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let _ = writeln!(
            out,
            "| `{}` | {} | {} | {} |",
            cell(&input),
            report.episodes.len(),
            report.episodes.iter().sum::<usize>(),
            report.dropped_frames
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::sync::{Gap, StreamKind, StreamReport};

    #[test]
    fn the_readme_fills_what_the_recordings_state_and_keeps_the_template_headings() {
        let report = SyncReport {
            fps: 30,
            tolerance_ms: 50.0,
            on_gap: OnGap::Split,
            grid: Some((0, 1_000)),
            streams: vec![StreamReport {
                topic: "/cam/left|x".into(),
                kind: StreamKind::Sampled,
                count: 90,
                rate_hz: 29.97,
                jitter_ms: 0.25,
                gaps: vec![Gap { start: 5, end: 900 }],
                out_of_order: 2,
            }],
            dropped_frames: 3,
            episodes: vec![60, 48],
        };
        let preset = DvrkPreset::new(&["PSM1".into()], &[("left".into(), "/cam/left|x".into())]);
        let mut info =
            DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 30, "dvrk", Vec::new());
        info.splits = vec![("train".into(), 0..1), ("recovery".into(), 1..2)];
        let reports = [(Path::new("/data/run1.bag"), &report)];
        let text = readme(&ReadmeFacts {
            name: "suturing",
            info: &info,
            preset: &preset,
            task: Some("pass the needle"),
            reports: &reports,
        });
        for heading in [
            "# suturing - README",
            "## 📋 At a Glance",
            "## ⏱️ Data Synchronization Approach",
            "## 👥 Attribution & Contact",
        ] {
            assert!(text.contains(heading), "{heading} missing");
        }
        assert!(text.contains("| **Total Trajectories** | `2` |"), "{text}");
        assert!(text.contains("| **Total Hours** | `0.001` |"), "{text}");
        assert!(
            !text.contains("{hours}") && !text.contains("{sync}"),
            "{text}"
        );
        assert!(text.contains("`recovery` 1:2"), "{text}");
        assert!(text.contains("more than 50 ms old"), "{text}");
        assert!(
            text.contains("| `run1.bag` | `/cam/left x` | 90 | 30.0 | 0.25 | 1 | 2 |"),
            "{text}"
        );
        assert!(text.contains("| `run1.bag` | 2 | 108 | 3 |"), "{text}");
        assert!(text.contains("@ 30.0 Hz measured"), "{text}");
    }
}
