//! The DP3 zarr store in the format registry: a folder with `.zgroup`, `.zarray` or `.zattrs`.
//! Validated, written and merged (chunks re-packed, `merge.rs`); surgvla does not read it back
//! as episodes.

use crate::export::findings::{Findings, Format, ValidateOptions};
use crate::export::format::{DatasetFormat, Found, MergeError, MergeRequest, Probe, Sniff};
use crate::export::info::DatasetInfo;
use crate::export::{EpisodeSink, ExportError, SinkOptions, Summary};
use std::path::Path;

/// The DP3 zarr v2 store.
pub struct ZarrFormat;

impl DatasetFormat for ZarrFormat {
    fn name(&self) -> &'static str {
        "zarr"
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        if probe.has(".zgroup") || probe.has(".zarray") || probe.has(".zattrs") {
            Sniff::Yes(Found {
                format: Format::Zarr,
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
        matches!(options, SinkOptions::Zarr(_))
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        options: &SinkOptions,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        let SinkOptions::Zarr(options) = options else {
            return Err(ExportError::Internal("not zarr options".into()));
        };
        super::ZarrWriter::boxed(root, info, *options, resuming)
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}
