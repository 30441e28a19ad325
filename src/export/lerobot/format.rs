//! LeRobot in the format registry: a folder with `meta/` (or `data/` holding parquet) is
//! LeRobot; `codebase_version` (or, without a readable info.json, the JSON-lines metadata)
//! tells v3.0 from v2.1.

use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::format::{DatasetFormat, Found, Holds, MergeError, MergeRequest, Probe, Sniff};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, EpisodeSource, ExportError, SinkOptions, SourceOptions, Summary};
use std::path::Path;

/// LeRobot v3.0 and v2.1.
pub struct LeRobotFormat;

impl DatasetFormat for LeRobotFormat {
    fn name(&self) -> &'static str {
        "lerobot"
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        let path = &probe.path;
        if probe.is_file
            || !(probe.has("meta") || probe.has("data") && has_parquet(&path.join("data")))
        {
            return Sniff::No;
        }
        let found = Found {
            format: version(path),
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

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
        super::check::check(&found.root, found.format, options, findings)
    }

    fn writes(&self, options: &SinkOptions) -> bool {
        matches!(options, SinkOptions::LeRobot(_))
    }

    fn holds(&self) -> Holds {
        Holds {
            video: true,
            other_features: true,
        }
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        options: &SinkOptions,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        let SinkOptions::LeRobot(options) = options else {
            return Err(ExportError::Internal("not LeRobot options".into()));
        };
        super::LeRobotWriter::boxed(root, info, options.clone(), resuming)
    }

    fn open_source(
        &self,
        found: &Found,
        _options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        Some(
            super::read::LeRobotSource::open(&found.root)
                .map(|source| Box::new(source) as Box<dyn EpisodeSource + Send>),
        )
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
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
fn version(root: &Path) -> Format {
    if let Ok(info) = super::read::read_info(&root.join("meta/info.json")) {
        return if info.is_v21() {
            Format::LeRobotV21
        } else {
            Format::LeRobotV30
        };
    }
    if root.join("meta/episodes.jsonl").exists() || root.join("meta/tasks.jsonl").exists() {
        return Format::LeRobotV21;
    }
    Format::LeRobotV30
}
