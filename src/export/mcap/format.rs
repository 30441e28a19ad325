//! MCAP in the format registry: an MCAP file (by its magic bytes or its `.mcap` name) or a
//! folder of them. Validated and written; surgvla does not read it back as episodes.

use super::writer::McapOptions;
use crate::export::error::ExportError;
use crate::export::findings::{Counts, Findings, ValidateOptions};
use crate::export::format::{
    Capabilities, DatasetFormat, Format, Found, MergeError, MergeRequest, Probe, SinkOptions, Sniff,
};
use crate::export::info::DatasetInfo;
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use std::path::Path;

/// An MCAP file's first bytes.
const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// MCAP recordings, one per episode.
pub struct McapFormat;

impl DatasetFormat for McapFormat {
    fn name(&self) -> &'static str {
        "mcap"
    }

    fn title(&self) -> &'static str {
        "MCAP"
    }

    fn help(&self) -> &'static str {
        "One MCAP recording per episode for Foxglove (images, depth, point cloud, frames, state, action); see --points, --crop"
    }

    fn layouts(&self) -> &'static [&'static str] {
        &["mcap"]
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            merges: true,
            point_clouds: true,
            other_features: crate::export::roles::Others::All,
            needs_camera: true,
            ..Capabilities::default()
        }
    }

    fn schema_help(&self) -> Option<&'static str> {
        Some("The JSON Schemas of an MCAP recording's JSON channels, by topic")
    }

    fn schema(&self, _info: &DatasetInfo) -> Option<serde_json::Value> {
        Some(super::messages::json_channel_schemas())
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        let recognised = if probe.is_file {
            probe.magic == MAGIC || probe.path.extension().is_some_and(|e| e == "mcap")
        } else {
            probe.entries.iter().any(|e| e.ends_with(".mcap"))
        };
        if recognised {
            Sniff::Yes(Found {
                layout: "mcap",
                root: probe.path.clone(),
            })
        } else {
            Sniff::No
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> Counts {
        Counts::from(super::check::check(&found.root, options, findings))
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}

impl SinkOptions for McapOptions {
    fn format(&self) -> Format {
        Format(&McapFormat)
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        super::writer::McapWriter::boxed(root, info, *self, resuming)
    }
}
