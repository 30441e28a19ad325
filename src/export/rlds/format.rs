//! RLDS in the format registry: a TFDS version folder (`dataset_info.json`, `features.json`,
//! TFRecord shards) or the data directory above one. Datasets with `surgvla.json` beside
//! `dataset_info.json` are ours ([`super::read::RldsSource`]); others are read through their
//! own `features.json` ([`super::foreign::ForeignRldsSource`]) and need a frame rate.

use super::options::RldsOptions;
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

/// RLDS in the TFDS layout.
pub struct RldsFormat;

impl DatasetFormat for RldsFormat {
    fn name(&self) -> &'static str {
        "rlds"
    }

    fn title(&self) -> &'static str {
        "RLDS"
    }

    fn help(&self) -> &'static str {
        "RLDS in the TFDS layout (tensorflow_datasets, OpenVLA, Octo); see --rlds-name"
    }

    fn layouts(&self) -> &'static [&'static str] {
        &["rlds"]
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            reads: true,
            merges: true,
            video: false,
            other_features: crate::export::roles::Others::All,
            needs_camera: false,
            point_clouds: false,
        }
    }

    fn schema_help(&self) -> Option<&'static str> {
        Some("RLDS's features.json")
    }

    fn schema(&self, info: &DatasetInfo) -> Option<serde_json::Value> {
        Some(super::features::features_json(
            info,
            &RldsOptions::default(),
        ))
    }

    /// The card sits in the TFDS data directory, above the `<name>/<version>` folder.
    fn card_folder<'a>(&self, found: &'a Found) -> Option<&'a Path> {
        found.root.parent().and_then(Path::parent)
    }

    fn sniff(&self, probe: &Probe) -> Sniff {
        if probe.is_file {
            return Sniff::No;
        }
        let found = |root: &Path| Found {
            layout: "rlds",
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

    /// A TFDS data directory of several datasets (`~/tensorflow_datasets`): which are there.
    fn several(&self, probe: &Probe) -> Option<String> {
        let found = super::read::datasets_below(&probe.path);
        (found.len() > 1).then(|| {
            let names: Vec<&str> = found.iter().map(|(name, _)| name.as_str()).collect();
            format!(
                "is a TFDS data directory of several RLDS datasets ({}): give one of them as {}/<name>",
                names.join(", "),
                probe.path.display()
            )
        })
    }

    fn check(&self, found: &Found, options: &ValidateOptions, findings: &Findings) -> Counts {
        Counts::from(super::check::check(&found.root, options, findings))
    }

    fn open_source(
        &self,
        found: &Found,
        options: &SourceOptions,
    ) -> Option<Result<Box<dyn EpisodeSource + Send>, ExportError>> {
        Some(super::foreign::open_any(&found.root, options))
    }

    fn merge(&self, request: &mut MergeRequest<'_>) -> Option<Result<Summary, MergeError>> {
        Some(super::merge::merge(request))
    }

    /// The options the dataset's manifest records (surgvla's), else the defaults under the
    /// dataset's own name and version (its folders').
    fn options_like(
        &self,
        found: &Found,
        _info: &DatasetInfo,
    ) -> Option<Result<Box<dyn SinkOptions>, ExportError>> {
        let version = found.root.file_name()?.to_string_lossy().into_owned();
        let named = found.root.parent()?;
        let name = named.file_name()?.to_string_lossy().into_owned();
        let manifest = named.parent()?.join(super::options::MANIFEST);
        let recorded = crate::export::bounded::read_json(&manifest)
            .ok()
            .map(|m| crate::export::dir::RunOptions::from_manifest(&m))
            .and_then(|run| RldsOptions::from_run_options(&run));
        let options = recorded.unwrap_or(RldsOptions {
            name,
            version,
            ..RldsOptions::default()
        });
        Some(Ok(Box::new(options)))
    }
}

impl SinkOptions for RldsOptions {
    fn format(&self) -> Format {
        Format(&RldsFormat)
    }

    fn check(&self) -> Result<(), ExportError> {
        RldsOptions::check(self)
    }

    fn open_sink(
        &self,
        root: &Path,
        info: &DatasetInfo,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
        super::writer::RldsWriter::boxed(root, info, self.clone(), resuming)
    }
}
