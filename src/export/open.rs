//! Opening datasets through the registry: [`open_sink`] starts (or resumes) the sink of the
//! format whose options it is given, after refusing features that format cannot hold;
//! [`open_source`] finds a path's format and opens its reader. What a conversion must decode
//! ([`decoding_needed`]) is asked of the options and their format.

use crate::episode::FeatureKind;
use crate::export::collection::Shard;
use crate::export::convert::{ConvertError, Without};
use crate::export::decoded::Decoded;
use crate::export::dir::resumes;
use crate::export::error::ExportError;
use crate::export::format::SinkOptions;
use crate::export::identity;
use crate::export::info::DatasetInfo;
use crate::export::registry;
use crate::export::roles::{Others, RoleSource, Roles};
use crate::export::shard::Sharded;
use crate::export::sink::EpisodeSink;
use crate::export::source::{EpisodeSource, SourceOptions};
use std::path::{Path, PathBuf};

/// Whether a conversion of a dataset of `info` into `options` must decode its video (through
/// [`Decoded`]): the format does not store video, or the options ask for another codec than a
/// video feature's.
pub fn decoding_needed(info: &DatasetInfo, options: &dyn SinkOptions) -> bool {
    Decoded::needed(info) && (!options.format().capabilities().video || options.reencodes(info))
}

/// Starts a dataset of `info` in `root` (which must not exist or be empty), or, when
/// [`resumes`], continues it from its last checkpoint ([`EpisodeSink::next_episode_index`] says
/// where), in the format whose `options` these are.
pub fn open_sink(
    root: &Path,
    info: &DatasetInfo,
    options: &dyn SinkOptions,
    resume: bool,
) -> Result<Box<dyn EpisodeSink + Send>, ExportError> {
    options.check()?;
    let holds = options.format().capabilities();
    let videos: Vec<String> = info
        .features
        .iter()
        .filter_map(|f| Some(format!("{} ({})", f.name, f.video?.name())))
        .collect();
    if !videos.is_empty() && !holds.video {
        return Err(ExportError::InvalidOptions(format!(
            "the input stores {} as video, which this format needs decoded (read the input through export::decoded::Decoded)",
            videos.join(", ")
        )));
    }
    let others: Vec<&str> = info
        .features
        .iter()
        .filter(|f| f.kind == FeatureKind::Other && !holds.other_features.hold(f))
        .map(|f| f.name.as_str())
        .collect();
    let title = options.format().title();
    if !others.is_empty() {
        return Err(ExportError::InvalidOptions(format!(
            "the features {} have no place in {title} (convert leaves them out with a note; {} keep them)",
            others.join(", "),
            registry::titles(|c| c.other_features == Others::All, "or"),
        )));
    }
    if holds.needs_camera && !info.has(FeatureKind::Rgb) {
        return Err(ExportError::InvalidOptions(format!(
            "{title} is built around one RGB camera, which this dataset does not name (convert --camera KEY names one)"
        )));
    }
    options.open_sink(root, info, resumes(root, resume))
}

/// Opens a dataset for reading, detecting its format through the registry (LeRobot, or RLDS:
/// a TFDS version folder or the data directory above it). A path holding nothing recognised,
/// or a format surgvla does not read, is the user's error.
pub fn open_source(root: &Path) -> Result<Box<dyn EpisodeSource + Send>, ExportError> {
    open_source_with(root, &SourceOptions::default())
}

/// [`open_source`] with what the dataset may not say: an RLDS dataset surgvla did not write
/// (no `surgvla.json` beside its `dataset_info.json`) is read through its own `features.json`
/// and needs `options.fps`.
pub fn open_source_with(
    root: &Path,
    options: &SourceOptions,
) -> Result<Box<dyn EpisodeSource + Send>, ExportError> {
    let (format, found) = registry::detect_readable(root)?;
    if !options.map.is_empty() && format.name() != "rlds" {
        return Err(ExportError::InvalidOptions(format!(
            "--map is for RLDS datasets another tool wrote; {} is {}, whose features are named already (--without leaves one out)",
            found.root.display(),
            format.title()
        )));
    }
    let source = format.open_source(&found, options).unwrap_or_else(|| {
        Err(ExportError::NotReadable {
            path: found.root.clone(),
            format: found.layout,
            readers: registry::titles(|c| c.reads, "and"),
        })
    })?;
    Ok(Box::new(identity::Identified::new(source, &found.root)?))
}

/// What `convert` reads: the input, what it may not say, one shard of it, the optional
/// features left out, and whether video is decoded even where the target could copy it.
#[derive(Clone, Debug, Default)]
pub struct ConvertInput {
    pub path: PathBuf,
    pub source: SourceOptions,
    pub shard: Shard,
    /// Features left out, as the user names them: `depth`, `mask`, `environment_state`
    /// (surgvla's optional features) or any feature key of the input
    /// ([`Without::resolve`] checks them against its features).
    pub without: Vec<String>,
    /// Decode video features to pixels even where the target stores video.
    pub decode: bool,
    /// Which of another tool's features are the camera and depth of a target built around
    /// them (zarr, MCAP, PLY, PCD).
    pub roles: Roles,
}

impl ConvertInput {
    /// The input as it is converted into `options`: opened, its shard taken, features left out,
    /// and its video decoded when asked or when the target needs pixels.
    pub fn open(
        &self,
        options: &dyn SinkOptions,
    ) -> Result<Box<dyn EpisodeSource + Send>, ConvertError> {
        let reading = SourceOptions {
            without: self.without.clone(),
            ..self.source.clone()
        };
        let mut source = open_source_with(&self.path, &reading).map_err(ConvertError::Read)?;
        if self.shard != Shard::default() {
            // Usage: a shard past the input's episodes, or an input that is itself a shard.
            source = Box::new(Sharded::new(source, self.shard).map_err(ConvertError::Input)?);
        }
        // What the reader left out already (video it cannot decode) is done.
        let without: Vec<String> = (self.without.iter())
            .filter(|name| !source.info().omitted.contains(name))
            .cloned()
            .collect();
        if !without.is_empty() {
            let (kinds, names) = Without::resolve(source.info(), &without)
                .map_err(|problem| ConvertError::Input(ExportError::InvalidOptions(problem)))?;
            source = Box::new(Without::with_names(source, &kinds, &names));
        }
        let needed = decoding_needed(source.info(), options);
        if needed || (self.decode && Decoded::needed(source.info())) {
            source = Box::new(Decoded::new(source).map_err(ConvertError::Input)?);
        }
        let format = options.format();
        let holds = format.capabilities();
        if !holds.needs_camera {
            if !self.roles.is_empty() {
                return Err(ConvertError::Input(ExportError::InvalidOptions(format!(
                    "--camera, --depth, --depth-unit-m and --intrinsics name the camera of {}; {} keeps every feature as it is",
                    registry::titles(|c| c.needs_camera, "and"),
                    format.title()
                ))));
            }
            return Ok(source);
        }
        let info = source.info();
        let left_out = (info.features.iter())
            .any(|f| f.kind == FeatureKind::Other && !holds.other_features.hold(f));
        if self.roles.is_empty() && info.has(FeatureKind::Rgb) && !left_out {
            return Ok(source);
        }
        let roled = RoleSource::new(source, &self.roles, holds.other_features, format.title())
            .map_err(ConvertError::Input)?;
        Ok(Box::new(roled))
    }
}
