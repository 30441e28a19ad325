//! RLDS in the TFDS on-disk layout, written without TensorFlow (see `../shared/spec/rlds.md`):
//! [`RldsWriter`] (an [`EpisodeSink`]) and [`read::RldsSource`].
//!
//! Layout, in the output folder (TFDS's `data_dir`):
//! ```text
//! <name>/<version>/dataset_info.json                   name, version, shardLengths (checked)
//! <name>/<version>/features.json                       the feature tree readers decode with
//! <name>/<version>/<name>-train.tfrecord-NNNNN-of-MMMMM  one tf.train.Example per episode
//! <name>/<version>/surgvla.json                        camera, mask ids, collection, RLDS keys
//! OPENVLA.md                                           how to fine-tune OpenVLA on it
//! surgvla_manifest.json                                every file with size and CRC-32C
//! ```
//! Shards roll once they reach [`RldsOptions::shard_size_mb`] (TFDS sizes shards from 64 MiB
//! up) and are written as `<name>-train.tfrecord-NNNNN` until the run finishes: only then is
//! the count `MMMMM` known, and [`DatasetDir::rename_files`] gives them their final names (a
//! resume after an interruption there undoes the renames first). Every closed shard is a
//! checkpoint. Encodings: TFRecord framing with masked CRC-32C ([`tfrecord`]),
//! `tf.train.Example` ([`example`]), episodes ([`record`]), metadata ([`features`]).

pub mod check;
pub mod example;
pub mod features;
pub mod foreign;
mod format;
pub mod generic;
pub mod merge;
mod openvla;
pub mod read;
pub mod record;
pub mod tfrecord;

pub use format::RldsFormat;
pub use openvla::openvla_md;

use crate::episode::{Episode, FeatureKind, ImageEncoding};
use crate::export::dir::{DatasetDir, PendingFile, RunOptions};
use crate::media::image::PngLevel;
use crate::export::info::DatasetInfo;
use crate::export::writer::{EpisodeEncoder, FormatWriter, Writer};
use crate::export::error::ExportError;
use crate::export::sink::Summary;
use record::{StepLayout, encode_episode, encode_foreign_episode};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::io::{BufWriter, Write};

/// Every file with its size and CRC-32C, at the top of the output folder.
pub const MANIFEST: &str = "surgvla_manifest.json";
/// The guide beside the dataset.
pub const OPENVLA_GUIDE: &str = "OPENVLA.md";
/// surgvla's own metadata inside the version folder.
pub const SURGVLA_JSON: &str = "surgvla.json";

/// Where another tool's feature goes in an RLDS step: `observation.images.X` ->
/// `observation/X`, otherwise its dotted name as a path (`observation.state` ->
/// `observation/state`, `action` -> `action`); [`foreign`] reads the names back.
pub fn rlds_path(name: &str) -> Vec<String> {
    match name.strip_prefix("observation.images.") {
        Some(camera) => vec!["observation".into(), camera.replace('.', "_")],
        None => name.split('.').map(String::from).collect(),
    }
}

/// The observation keys of a step (`steps/observation/<key>`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RldsKeys {
    /// The RGB camera (OpenVLA's primary image key).
    pub image: String,
    pub depth: String,
    pub mask: String,
    pub state: String,
    pub environment_state: String,
}

impl Default for RldsKeys {
    /// OpenVLA-friendly names: `image`, `depth`, `mask`, `state`, `environment_state`.
    fn default() -> Self {
        RldsKeys {
            image: "image".into(),
            depth: "depth".into(),
            mask: "mask".into(),
            state: "state".into(),
            environment_state: "environment_state".into(),
        }
    }
}

/// Options of the RLDS format.
#[derive(Clone, Debug, PartialEq)]
pub struct RldsOptions {
    /// The dataset name (folder and shard prefix; what `tfds.builder(name)` takes).
    pub name: String,
    /// The version folder, x.y.z.
    pub version: String,
    /// A shard is closed once it reaches this size.
    pub shard_size_mb: u64,
    pub png: PngLevel,
    pub keys: RldsKeys,
    /// The RGB camera as JPEG of this quality (1-100) instead of PNG: what Open X-Embodiment
    /// and OpenVLA's datasets store, a fraction of the size, lossy.
    pub jpeg_quality: Option<u8>,
}

impl Default for RldsOptions {
    fn default() -> Self {
        RldsOptions {
            name: "surgvla_benchmark".into(),
            version: "1.0.0".into(),
            shard_size_mb: 64,
            png: PngLevel::Fast,
            keys: RldsKeys::default(),
            jpeg_quality: None,
        }
    }
}

impl RldsOptions {
    /// Refuses a name TFDS cannot load, a version that is not x.y.z, or keys that are empty,
    /// contain '/' or repeat.
    pub fn check(&self) -> Result<(), ExportError> {
        let bad = |problem: String| Err(ExportError::InvalidOptions(problem));
        let name = &self.name;
        let snake = name.starts_with(|c: char| c.is_ascii_lowercase())
            && name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !snake {
            return bad(format!(
                "RLDS name {name:?} must be snake_case (a-z, 0-9, _; starting with a letter), as tfds.builder requires"
            ));
        }
        let parts: Vec<&str> = self.version.split('.').collect();
        if parts.len() != 3
            || parts
                .iter()
                .any(|p| p.is_empty() || !p.chars().all(|c| c.is_ascii_digit()))
        {
            return bad(format!(
                "RLDS version {:?} must be x.y.z, e.g. 1.0.0",
                self.version
            ));
        }
        let keys = &self.keys;
        let all = [
            &keys.image,
            &keys.depth,
            &keys.mask,
            &keys.state,
            &keys.environment_state,
        ];
        for (i, key) in all.iter().enumerate() {
            let ok = !key.is_empty()
                && key
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            if !ok {
                return bad(format!(
                    "RLDS observation key {key:?} must be non-empty letters, digits, _ or -"
                ));
            }
            if all[..i].contains(key) {
                return bad(format!("RLDS observation key {key:?} is given twice"));
            }
        }
        Ok(())
    }

    /// What these options change in the bytes, by option name (for resume).
    pub fn run_options(&self) -> RunOptions {
        let mut options = RunOptions::default();
        options.set("format", "rlds".into());
        options.set("rlds_name", self.name.clone().into());
        options.set("rlds_version", self.version.clone().into());
        options.set("rlds_shard_mb", self.shard_size_mb.into());
        options.set("png", format!("{:?}", self.png).into());
        options.set("rlds_keys", json!(self.keys));
        if let Some(quality) = self.jpeg_quality {
            options.set("rlds_jpeg_quality", quality.into());
        }
        options
    }

    /// The options a dataset recorded ([`RldsOptions::run_options`], in its manifest); None
    /// when an option is missing or not of its type.
    pub fn from_run_options(run: &RunOptions) -> Option<RldsOptions> {
        let text = |key: &str| run.get(key)?.as_str().map(String::from);
        let png = match text("png")?.as_str() {
            "Fast" => PngLevel::Fast,
            "Default" => PngLevel::Default,
            "Best" => PngLevel::Best,
            _ => return None,
        };
        let jpeg_quality = match run.get("rlds_jpeg_quality") {
            None => None,
            Some(quality) => Some(u8::try_from(quality.as_u64()?).ok()?),
        };
        Some(RldsOptions {
            name: text("rlds_name")?,
            version: text("rlds_version")?,
            shard_size_mb: run.get("rlds_shard_mb")?.as_u64()?,
            png,
            keys: serde_json::from_value(run.get("rlds_keys")?.clone()).ok()?,
            jpeg_quality,
        })
    }

    /// The version folder, relative to the output folder.
    pub fn version_dir(&self) -> String {
        format!("{}/{}", self.name, self.version)
    }

    /// Shard `index` of `count` (`count` None: the name while the run is going on).
    pub fn shard_path(&self, index: usize, count: Option<usize>) -> String {
        let base = format!(
            "{}/{}-train.tfrecord-{index:05}",
            self.version_dir(),
            self.name
        );
        match count {
            Some(count) => format!("{base}-of-{count:05}"),
            None => base,
        }
    }
}

/// The writer's state at a checkpoint (every shard closed): what the metadata needs.
#[derive(Clone, Default, Serialize, Deserialize)]
pub struct State {
    /// Episodes in each closed shard.
    shard_lengths: Vec<u64>,
    episodes: u64,
    /// Serialized Example bytes (dataset_info's numBytes).
    example_bytes: u64,
    summary: Summary,
}

/// The shard being written.
struct OpenShard {
    writer: BufWriter<std::fs::File>,
    pending: PendingFile,
    bytes: u64,
    episodes: u64,
}

/// Streams episodes into an RLDS dataset: one Example per episode, rolled into shards.
pub type RldsWriter = Writer<RldsShards>;

/// RLDS's part of [`RldsWriter`].
pub struct RldsShards {
    options: RldsOptions,
    layout: StepLayout,
    open: Option<OpenShard>,
    state: State,
}

impl FormatWriter for RldsShards {
    type Options = RldsOptions;
    type State = State;
    /// The episode's serialized `tf.train.Example`.
    type Encoded = Vec<u8>;
    type Encoder<'a> = (&'a Self, &'a DatasetInfo);
    const MANIFEST: &'static str = MANIFEST;

    fn card_format(&self) -> crate::export::card::CardFormat {
        crate::export::card::CardFormat {
            name: "rlds",
            data_files: None,
            video: Vec::new(),
        }
    }

    fn run_options(info: &DatasetInfo, options: &RldsOptions) -> Result<RunOptions, ExportError> {
        options.check()?;
        let shapes_fit = info
            .features
            .iter()
            .all(|f| f.dtype != crate::episode::Dtype::Image || f.shape.len() == 3);
        let others = info.features.iter().any(|f| f.kind == FeatureKind::Other);
        if info.is_ours() && others {
            return Err(ExportError::InvalidOptions(
                "RLDS holds either surgvla's features or another tool's, not both".into(),
            ));
        }
        if info.is_ours() && info.rgb_key().is_none() || !shapes_fit {
            return Err(ExportError::InvalidOptions(
                "RLDS needs an RGB camera feature and images of height x width x channels".into(),
            ));
        }
        let mut run = info.run_options();
        run.merge(options.run_options());
        Ok(run)
    }

    fn owned_folders(options: &RldsOptions) -> Vec<String> {
        vec![options.name.clone()]
    }

    fn new(
        _: &DatasetDir,
        info: &DatasetInfo,
        options: RldsOptions,
        state: Option<State>,
    ) -> Result<Self, ExportError> {
        Ok(RldsShards {
            layout: StepLayout {
                jpeg_quality: options.jpeg_quality,
                ..StepLayout::of(info, &options.keys)
            },
            options,
            open: None,
            state: state.unwrap_or_default(),
        })
    }

    fn episodes(&self) -> u64 {
        self.state.episodes
    }

    /// Depth is stored in millimetres, never as the source's float TIFF.
    fn reuses_stored(&self, encoding: ImageEncoding) -> bool {
        encoding != ImageEncoding::Tiff
    }

    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> (&'a Self, &'a DatasetInfo) {
        (self, info)
    }

    fn append(
        &mut self,
        dir: &mut DatasetDir,
        _: &DatasetInfo,
        episode: &Episode,
        example: Vec<u8>,
    ) -> Result<f64, ExportError> {
        self.append_example(dir, &example, episode.steps.len() as u64)?;
        Ok(0.0)
    }

    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError> {
        self.finish_dataset(dir, info)
    }
}

impl RldsShards {
    /// Appends one serialized episode to the open shard (opening one), closing the shard and
    /// checkpointing once it is full.
    fn append_example(
        &mut self,
        dir: &mut DatasetDir,
        example: &[u8],
        steps: u64,
    ) -> Result<(), ExportError> {
        if self.open.is_none() {
            let index = self.state.shard_lengths.len();
            let (file, pending) = dir.create_file(&self.options.shard_path(index, None))?;
            self.open = Some(OpenShard {
                writer: BufWriter::with_capacity(1 << 20, file),
                pending,
                bytes: 0,
                episodes: 0,
            });
        }
        let shard = self
            .open
            .as_mut()
            .ok_or_else(|| ExportError::Internal("no open shard".into()))?;
        tfrecord::write_record(&mut shard.writer, example)
            .map_err(ExportError::io(&shard.pending.path))?;
        shard.bytes += tfrecord::framed_len(example.len());
        shard.episodes += 1;
        let full = shard.bytes >= self.options.shard_size_mb * 1024 * 1024;
        self.state.episodes += 1;
        self.state.example_bytes += example.len() as u64;
        self.state.summary.episodes += 1;
        self.state.summary.frames += steps;
        if full {
            self.close_shard(dir)?;
            dir.save_checkpoint(&self.state)?;
        }
        Ok(())
    }

    fn close_shard(&mut self, dir: &mut DatasetDir) -> Result<(), ExportError> {
        if let Some(mut shard) = self.open.take() {
            let path = shard.pending.path.clone();
            shard.writer.flush().map_err(ExportError::io(&path))?;
            drop(shard.writer);
            let bytes = dir.commit(shard.pending)?;
            self.state.shard_lengths.push(shard.episodes);
            self.state.summary.files += 1;
            self.state.summary.bytes += bytes;
        }
        Ok(())
    }

    /// Writes a metadata file and counts it.
    fn write_file(
        dir: &mut DatasetDir,
        summary: &mut Summary,
        relative: &str,
        bytes: &[u8],
    ) -> Result<(), ExportError> {
        summary.bytes += dir.write_atomically(relative, bytes)?;
        summary.files += 1;
        Ok(())
    }

    fn json_bytes(
        dir: &DatasetDir,
        relative: &str,
        value: &serde_json::Value,
    ) -> Result<Vec<u8>, ExportError> {
        serde_json::to_vec_pretty(value).map_err(|source| ExportError::Json {
            path: dir.path(relative),
            source,
        })
    }

    /// Finishing, in an order an interruption at any point can resume: close the shard and
    /// checkpoint, give the shards their final names, write the metadata, the guide, the
    /// manifest and the sidecar, and only then remove the marker.
    fn finish_dataset(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
    ) -> Result<Summary, ExportError> {
        self.close_shard(dir)?;
        dir.save_checkpoint(&self.state)?;
        let count = self.state.shard_lengths.len();
        let renames: Vec<(String, String)> = (0..count)
            .map(|i| {
                (
                    self.options.shard_path(i, None),
                    self.options.shard_path(i, Some(count)),
                )
            })
            .collect();
        dir.rename_files(&renames, &self.state)?;
        let mut summary = self.state.summary.clone();
        let version_dir = self.options.version_dir();
        let ours = info.is_ours();
        let features = if ours {
            features::features_json(info, &self.options)
        } else {
            features::foreign_features_json(info)
        };
        let dataset_info = features::dataset_info_json(
            info,
            &self.options,
            &self.state.shard_lengths,
            self.state.example_bytes,
        );
        let mut surgvla = info.surgvla_json();
        surgvla["fps"] = json!(info.fps);
        surgvla["robot_type"] = json!(info.robot_type);
        surgvla["rlds"] = json!({"keys": self.options.keys, "depth_unit": "mm"});
        // A dataset another tool made gets no surgvla metadata (readers then take its
        // features from features.json) and no OpenVLA guide (its keys are not ours).
        for (file, value) in [
            ("features.json", features),
            (SURGVLA_JSON, surgvla),
            ("dataset_info.json", dataset_info),
        ] {
            if file == SURGVLA_JSON && !ours {
                continue;
            }
            let relative = format!("{version_dir}/{file}");
            let bytes = Self::json_bytes(dir, &relative, &value)?;
            Self::write_file(dir, &mut summary, &relative, &bytes)?;
        }
        if ours {
            let guide = openvla_md(info, &self.options);
            Self::write_file(dir, &mut summary, OPENVLA_GUIDE, guide.as_bytes())?;
        }
        Ok(summary)
    }
}

impl EpisodeEncoder<Vec<u8>> for (&RldsShards, &DatasetInfo) {
    fn encode(&self, episode: &Episode) -> Result<Vec<u8>, ExportError> {
        let (shards, info) = *self;
        if info.is_ours() {
            encode_episode(&shards.layout, episode, shards.options.png)
        } else {
            encode_foreign_episode(info, episode)
        }
    }
}

/// Reads an RLDS version folder: ours (with `surgvla.json`), or another tool's through its own
/// `features.json`, which needs `options.fps`.
pub fn open_any(
    folder: &std::path::Path,
    options: &crate::export::source::SourceOptions,
) -> Result<Box<dyn crate::export::source::EpisodeSource + Send>, ExportError> {
    if folder.join(SURGVLA_JSON).is_file() {
        return Ok(Box::new(read::RldsSource::open(folder)?));
    }
    let fps = options.fps.ok_or_else(|| ExportError::NoFrameRate {
        path: folder.to_path_buf(),
    })?;
    let robot_type = options.robot_type.as_deref().unwrap_or("unknown");
    Ok(Box::new(foreign::ForeignRldsSource::open(
        folder, fps, robot_type,
    )?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_refuse_names_tfds_cannot_load() {
        assert!(RldsOptions::default().check().is_ok());
        let with = |f: &dyn Fn(&mut RldsOptions)| {
            let mut options = RldsOptions::default();
            f(&mut options);
            options.check()
        };
        assert!(with(&|o| o.name = "Surg-VLA".into()).is_err());
        assert!(with(&|o| o.name = "9lives".into()).is_err());
        assert!(with(&|o| o.version = "1.0".into()).is_err());
        assert!(with(&|o| o.version = "1.0.x".into()).is_err());
        assert!(with(&|o| o.keys.state = "image".into()).is_err());
        assert!(with(&|o| o.keys.image = "a/b".into()).is_err());
        assert!(with(&|o| o.keys.image = "agentview_rgb".into()).is_ok());
    }

    #[test]
    fn options_are_read_back_from_what_a_dataset_records() {
        let options = RldsOptions {
            name: "other".into(),
            shard_size_mb: 3,
            png: PngLevel::Best,
            jpeg_quality: Some(90),
            ..RldsOptions::default()
        };
        let read = RldsOptions::from_run_options(&options.run_options());
        assert_eq!(read, Some(options));
        let default = RldsOptions::default();
        assert_eq!(
            RldsOptions::from_run_options(&default.run_options()),
            Some(default)
        );
        assert_eq!(RldsOptions::from_run_options(&RunOptions::default()), None);
    }

    #[test]
    fn shards_get_their_count_only_at_the_end() {
        let options = RldsOptions::default();
        assert_eq!(
            options.shard_path(3, None),
            "surgvla_benchmark/1.0.0/surgvla_benchmark-train.tfrecord-00003"
        );
        assert_eq!(
            options.shard_path(3, Some(12)),
            "surgvla_benchmark/1.0.0/surgvla_benchmark-train.tfrecord-00003-of-00012"
        );
    }
}
