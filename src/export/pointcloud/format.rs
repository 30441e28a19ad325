//! Point-cloud files in the format registry, one entry per file format ([`PLY`], [`PCD`]): a
//! folder whose `surgvla.json` states that `point_cloud.file_format`. Validated, written and
//! merged (files copied under new episode numbers, `merge.rs`); surgvla does not read clouds
//! back as episodes.

use super::cloud::CloudSettings;
use super::files::{CloudFileFormat, SURGVLA_JSON};
use crate::export::bounded::read_json;
use crate::export::error::ExportError;
use crate::export::findings::{Counts, Findings, ValidateOptions};
use crate::export::format::{
    Capabilities, DatasetFormat, Format, Found, MergeError, MergeRequest, Probe, SinkOptions, Sniff,
};
use crate::export::info::DatasetInfo;
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use std::path::Path;

/// The largest `surgvla.json` sniffing reads (ours are a few kilobytes).
const MAX_METADATA_BYTES: u64 = 1 << 20;

/// One PLY or PCD file per frame: [`PLY`] and [`PCD`].
pub struct CloudFilesFormat(pub CloudFileFormat);

/// One PLY file per frame.
pub static PLY: CloudFilesFormat = CloudFilesFormat(CloudFileFormat::Ply);
/// One PCD file per frame.
pub static PCD: CloudFilesFormat = CloudFilesFormat(CloudFileFormat::Pcd);

impl CloudFilesFormat {
    /// The registry's entry of `format`.
    pub fn of(format: CloudFileFormat) -> Format {
        match format {
            CloudFileFormat::Ply => Format(&PLY),
            CloudFileFormat::Pcd => Format(&PCD),
        }
    }
}

impl DatasetFormat for CloudFilesFormat {
    fn name(&self) -> &'static str {
        self.0.extension()
    }

    fn title(&self) -> &'static str {
        match self.0 {
            CloudFileFormat::Ply => "PLY",
            CloudFileFormat::Pcd => "PCD",
        }
    }

    fn help(&self) -> &'static str {
        match self.0 {
            CloudFileFormat::Ply => {
                "One PLY point cloud per frame (Open3D, CloudCompare); see --points, --crop"
            }
            CloudFileFormat::Pcd => {
                "One PCD v0.7 point cloud per frame (PCL, Open3D); see --points, --crop"
            }
        }
    }

    fn layouts(&self) -> &'static [&'static str] {
        match self.0 {
            CloudFileFormat::Ply => &["ply"],
            CloudFileFormat::Pcd => &["pcd"],
        }
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            merges: true,
            point_clouds: true,
            needs_camera: true,
            ..Capabilities::default()
        }
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
        let ours = read_json(&path).ok().is_some_and(|surgvla| {
            surgvla["point_cloud"]["file_format"].as_str() == Some(self.0.extension())
        });
        if ours {
            Sniff::Yes(Found {
                layout: self.0.extension(),
                root: probe.path.clone(),
            })
        } else {
            Sniff::No
        }
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> Counts {
        Counts::from(super::check::check(
            &found.root,
            self.0.extension(),
            options,
            findings,
        ))
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }
}

/// The options of the point-cloud files: which file format, and how clouds are made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudFileOptions {
    pub format: CloudFileFormat,
    pub settings: CloudSettings,
}

impl SinkOptions for CloudFileOptions {
    fn format(&self) -> Format {
        CloudFilesFormat::of(self.format)
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        super::files::CloudFilesWriter::boxed(root, info, (self.format, self.settings), resuming)
    }
}
