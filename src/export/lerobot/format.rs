//! LeRobot in the format registry: a folder with `meta/` (or `data/` holding parquet) is
//! LeRobot; `codebase_version` (or, without a readable info.json, the JSON-lines metadata)
//! tells v3.0 from v2.1.

use super::options::LeRobotOptions;
use crate::export::error::ExportError;
use crate::export::findings::{Counts, Findings, ValidateOptions};
use crate::export::format::{
    Capabilities, DatasetFormat, Format, Found, MergeError, MergeRequest, Probe, SinkOptions, Sniff,
};
use crate::export::info::DatasetInfo;
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use crate::export::source::SourceOptions;
use std::path::Path;

/// LeRobot v3.0 and v2.1.
pub struct LeRobotFormat;

/// The v3.0 layout, as reports name it.
pub(super) const V30: &str = "lerobot-v3.0";
/// The v2.1 layout (one file per episode, JSON-lines metadata).
pub(super) const V21: &str = "lerobot-v2.1";

impl DatasetFormat for LeRobotFormat {
    fn name(&self) -> &'static str {
        "lerobot"
    }

    fn title(&self) -> &'static str {
        "LeRobot"
    }

    fn help(&self) -> &'static str {
        "LeRobot (v3.0 by default; see --lerobot-version)"
    }

    fn layouts(&self) -> &'static [&'static str] {
        &[V30, V21]
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            reads: true,
            merges: true,
            video: true,
            other_features: crate::export::roles::Others::All,
            needs_camera: false,
            point_clouds: false,
        }
    }

    fn records_splits(&self) -> bool {
        true
    }

    fn schema_help(&self) -> Option<&'static str> {
        Some("The `features` of LeRobot's meta/info.json")
    }

    fn schema(&self, info: &DatasetInfo) -> Option<serde_json::Value> {
        Some(super::writer::features_json(&info.features))
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        let path = &probe.path;
        if probe.is_file
            || !(probe.has("meta") || probe.has("data") && has_parquet(&path.join("data")))
        {
            return Sniff::No;
        }
        let found = Found {
            layout: version(path),
            root: path.clone(),
        };
        if path.join("meta/info.json").is_file() {
            Sniff::Yes(found)
        } else {
            Sniff::Broken {
                found,
                problem: "no meta/info.json: not a complete LeRobot dataset".into(),
            }
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> Counts {
        Counts::from(super::check::check(
            &found.root,
            found.layout == V21,
            options,
            findings,
        ))
    }

    fn open_source(
        &self,
        found: &Found,
        options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        Some(
            super::read::LeRobotSource::open_with(&found.root, options)
                .map(|source| Box::new(source) as Box<dyn EpisodeSource + Send>),
        )
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }

    fn options_like(
        &self,
        found: &Found,
        info: &DatasetInfo,
    ) -> Option<Result<Box<dyn SinkOptions>, ExportError>> {
        Some(
            super::carry::options_like(&found.root, info)
                .map(|options| Box::new(options) as Box<dyn SinkOptions>),
        )
    }

    fn carried_files(&self, found: &Found) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        super::carry::carried_files(&found.root)
    }
}

impl SinkOptions for LeRobotOptions {
    fn format(&self) -> Format {
        Format(&LeRobotFormat)
    }

    /// A video feature of another codec than the one asked for is decoded and encoded again.
    fn reencodes(&self, info: &DatasetInfo) -> bool {
        self.video.is_some_and(|video| {
            info.features
                .iter()
                .any(|f| f.video.is_some_and(|codec| codec != video.codec))
        })
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        super::writer::LeRobotWriter::boxed(root, info, self.clone(), resuming)
    }
}

/// Whether a LeRobot `data/` folder holds any parquet file (one level of chunk folders).
fn has_parquet(data: &Path) -> bool {
    let Ok(chunks) = std::fs::read_dir(data) else {
        return false;
    };
    chunks.flatten().any(|chunk| {
        std::fs::read_dir(chunk.path()).is_ok_and(|files| {
            files
                .flatten()
                .any(|f| f.path().extension().is_some_and(|e| e == "parquet"))
        })
    })
}

/// v2.1 when info.json says so or, without a readable info.json, when the metadata is JSON
/// lines; else v3.0.
fn version(root: &Path) -> &'static str {
    if let Ok(info) = super::read::read_info(&root.join("meta/info.json")) {
        return if info.is_v21() { V21 } else { V30 };
    }
    if root.join("meta/episodes.jsonl").exists() || root.join("meta/tasks.jsonl").exists() {
        return V21;
    }
    V30
}
