//! Point-cloud files in the format registry: a folder whose `surgvla.json` states a
//! `point_cloud.file_format` (PLY or PCD). Validated, written and merged (files copied under new
//! episode numbers, `merge.rs`); surgvla does not read clouds back as episodes.

use super::files::{CloudFileFormat, SURGVLA_JSON};
use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::format::{DatasetFormat, Found, MergeError, MergeRequest, Probe, Sniff};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, ExportError, SinkOptions, Summary, read_json};
use std::path::Path;

/// The largest `surgvla.json` sniffing reads (ours are a few kilobytes).
const MAX_METADATA_BYTES: u64 = 1 << 20;

/// One PLY or PCD file per frame.
pub struct CloudFilesFormat;

impl DatasetFormat for CloudFilesFormat {
    fn name(&self) -> &'static str {
        "point-cloud files"
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        if probe.is_file || !probe.has(SURGVLA_JSON) || !probe.has(super::files::EPISODES) {
            return Sniff::No;
        }
        // A sniff reads small metadata only: anything larger is not our surgvla.json.
        let path = probe.path.join(SURGVLA_JSON);
        if std::fs::metadata(&path).map_or(true, |m| m.len() > MAX_METADATA_BYTES) {
            return Sniff::No;
        }
        let format = read_json(&path).ok().and_then(|surgvla| {
            match surgvla["point_cloud"]["file_format"].as_str()? {
                "ply" => Some(Format::Ply),
                "pcd" => Some(Format::Pcd),
                _ => None,
            }
        });
        match format {
            Some(format) => Sniff::Yes(Found {
                format,
                root: probe.path.clone(),
            }),
            None => Sniff::No,
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
        let extension = match found.format {
            Format::Pcd => CloudFileFormat::Pcd,
            _ => CloudFileFormat::Ply,
        }
        .extension();
        super::check::check(&found.root, extension, options, findings)
    }

    fn writes(&self, options: &SinkOptions) -> bool {
        matches!(options, SinkOptions::CloudFiles(..))
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        options: &SinkOptions,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        let SinkOptions::CloudFiles(format, settings) = options else {
            return Err(ExportError::Internal("not point-cloud options".into()));
        };
        super::files::CloudFilesWriter::boxed(root, info, (*format, *settings), resuming)
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}
