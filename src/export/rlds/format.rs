//! RLDS in the format registry: a TFDS version folder (`dataset_info.json`, `features.json`,
//! TFRecord shards) or the data directory above one. Datasets with `surgvla.json` beside
//! `dataset_info.json` are ours ([`super::read::RldsSource`]); others are read through their
//! own `features.json` ([`super::foreign::ForeignRldsSource`]) and need a frame rate.

use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::format::{DatasetFormat, Found, Holds, MergeError, MergeRequest, Probe, Sniff};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, EpisodeSource, ExportError, SinkOptions, SourceOptions, Summary};
use std::path::Path;

/// RLDS in the TFDS layout.
pub struct RldsFormat;

impl DatasetFormat for RldsFormat {
    fn name(&self) -> &'static str {
        "rlds"
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        if probe.is_file {
            return Sniff::No;
        }
        let found = |root: &Path| Found {
            format: Format::Rlds,
            root: root.to_path_buf(),
        };
        let loose = probe.has("dataset_info.json")
            || probe.has("features.json")
            || probe.entries.iter().any(|e| e.contains(".tfrecord-"));
        match super::read::version_dir(&probe.path) {
            Ok(folder) => Sniff::Yes(found(&folder)),
            Err(error) if loose => Sniff::Broken {
                found: found(&probe.path),
                problem: error.to_string(),
            },
            Err(_) => Sniff::No,
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
        super::check::check(&found.root, options, findings)
    }

    fn writes(&self, options: &SinkOptions) -> bool {
        matches!(options, SinkOptions::Rlds(_))
    }

    fn holds(&self) -> Holds {
        Holds {
            video: false,
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
        let SinkOptions::Rlds(options) = options else {
            return Err(ExportError::Internal("not RLDS options".into()));
        };
        super::RldsWriter::boxed(root, info, options.clone(), resuming)
    }

    fn open_source(
        &self,
        found: &Found,
        options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        Some(super::open_any(&found.root, options))
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}
