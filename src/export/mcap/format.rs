//! MCAP in the format registry: an MCAP file (by its magic bytes or its `.mcap` name) or a
//! folder of them. Validated and written; surgvla does not read it back as episodes.

use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::format::{DatasetFormat, Found, MergeError, MergeRequest, Probe, Sniff};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, ExportError, SinkOptions, Summary};
use std::path::Path;

/// An MCAP file's first bytes.
const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// MCAP recordings, one per episode.
pub struct McapFormat;

impl DatasetFormat for McapFormat {
    fn name(&self) -> &'static str {
        "mcap"
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        let recognised = if probe.is_file {
            probe.magic == MAGIC || probe.path.extension().is_some_and(|e| e == "mcap")
        } else {
            probe.entries.iter().any(|e| e.ends_with(".mcap"))
        };
        if recognised {
            Sniff::Yes(Found {
                format: Format::Mcap,
                root: probe.path.clone(),
            })
        } else {
            Sniff::No
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
        super::check::check(&found.root, options, findings)
    }

    fn writes(&self, options: &SinkOptions) -> bool {
        matches!(options, SinkOptions::Mcap(_))
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        options: &SinkOptions,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        let SinkOptions::Mcap(options) = options else {
            return Err(ExportError::Internal("not MCAP options".into()));
        };
        super::McapWriter::boxed(root, info, *options, resuming)
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}
