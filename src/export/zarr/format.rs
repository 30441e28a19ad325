//! The DP3 zarr store in the format registry: a folder with `.zgroup`, `.zarray` or `.zattrs`.
//! Validated, written and merged (chunks re-packed, `merge.rs`); surgvla does not read it back
//! as episodes.

use super::writer::ZarrOptions;
use crate::export::error::ExportError;
use crate::export::findings::{Counts, Findings, ValidateOptions};
use crate::export::format::{
    Capabilities, DatasetFormat, Format, Found, MergeError, MergeRequest, Probe, SinkOptions, Sniff,
};
use crate::export::info::DatasetInfo;
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use std::path::Path;

/// The DP3 zarr v2 store.
pub struct ZarrFormat;

impl DatasetFormat for ZarrFormat {
    fn name(&self) -> &'static str {
        "zarr"
    }

    fn title(&self) -> &'static str {
        "zarr"
    }

    fn help(&self) -> &'static str {
        "The DP3 zarr v2 store (3D Diffusion Policy); see --points, --crop, --zarr-images"
    }

    fn layouts(&self) -> &'static [&'static str] {
        &["zarr"]
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            merges: true,
            point_clouds: true,
            other_features: crate::export::roles::Others::Vectors,
            needs_camera: true,
            ..Capabilities::default()
        }
    }

    /// A store has `meta/` and `data/` folders, which LeRobot's sniff would take.
    fn sniffed_first(&self) -> bool {
        true
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        if probe.has(".zgroup") || probe.has(".zarray") || probe.has(".zattrs") {
            Sniff::Yes(Found {
                layout: "zarr",
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

impl SinkOptions for ZarrOptions {
    fn format(&self) -> Format {
        Format(&ZarrFormat)
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        super::writer::ZarrWriter::boxed(root, info, *self, resuming)
    }
}
