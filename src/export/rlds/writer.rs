//! The RLDS writer: [`RldsWriter`] frames each episode's `tf.train.Example` into the open
//! TFRecord shard, closes shards by size (each a checkpoint), and at the end names them
//! `-NNNNN-of-MMMMM` and writes the TFDS metadata, `surgvla.json` and the OpenVLA guide.

use super::openvla::openvla_md;
use super::options::{MANIFEST, OPENVLA_GUIDE, RldsOptions, SURGVLA_JSON};
use super::record::{StepLayout, encode_episode, encode_foreign_episode};
use crate::episode::{Episode, FeatureKind, ImageEncoding};
use crate::export::dir::{DatasetDir, PendingFile, RunOptions};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::sink::Summary;
use crate::export::writer::{EpisodeEncoder, FormatWriter, Writer};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::io::{BufWriter, Write};

/// The writer's state at a checkpoint (every shard closed): what the metadata needs.
#[derive(Clone, Default, Serialize, Deserialize)]
pub struct State {
    /// Episodes in each closed shard.
    shard_lengths: Vec<u64>,
    episodes: u64,
    /// Serialized Example bytes (dataset_info's numBytes).
    example_bytes: u64,
    summary: Summary,
    /// Per image feature of another tool's dataset, the encoding its first frame is stored in
    /// ("png", "png16" for 16 bits per sample, "jpeg", "tiff": a float32 tensor of its shape):
    /// features.json declares it.
    #[serde(default)]
    image_formats: std::collections::BTreeMap<String, String>,
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
    /// The TFDS split the episodes go in ([`super::options::tfds_split`]).
    split: String,
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
            tagged: true,
            data_files: None,
            loading: Some(super::openvla::loading_snippet(&self.options, &self.split)),
            depth: "Stored as 1-channel uint16 PNG in millimetres: divide by 1000 for metres.",
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
        if !info.is_ours() {
            key_clash(info)?;
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
            split: super::options::tfds_split(&info.splits).to_string(),
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
        info: &DatasetInfo,
        episode: &Episode,
        example: Vec<u8>,
    ) -> Result<f64, ExportError> {
        if !info.is_ours() {
            self.note_image_formats(info, episode);
        }
        self.append_example(dir, &example, episode.steps.len() as u64)?;
        Ok(0.0)
    }

    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError> {
        self.finish_dataset(dir, info)
    }
}

/// Refuses features whose RLDS keys nest in each other (`action` and `action.gripper` would
/// be `steps/action` both as a value and as a folder, which features.json cannot say).
fn key_clash(info: &DatasetInfo) -> Result<(), ExportError> {
    let paths: Vec<(Vec<String>, &str)> = (info.features.iter())
        .map(|f| (super::options::rlds_path(&f.name), f.name.as_str()))
        .collect();
    for (path, name) in &paths {
        for (other, other_name) in &paths {
            if other.len() > path.len() && other.starts_with(path) {
                return Err(ExportError::InvalidOptions(format!(
                    "{name} and {other_name} would both be RLDS key steps/{}, as a value and as a folder; leave one out with --without {other_name}",
                    path.join("/")
                )));
            }
        }
    }
    Ok(())
}

impl RldsShards {
    /// Records the encoding of each image feature not seen before, from `episode`'s first
    /// frame (bytes are copied as stored: a JPEG another tool wrote stays JPEG).
    fn note_image_formats(&mut self, info: &DatasetInfo, episode: &Episode) {
        let Some(first) = episode.steps.first() else {
            return;
        };
        let images = (info.features.iter().zip(&first.other))
            .filter(|(f, _)| f.dtype == crate::episode::Dtype::Image);
        for (feature, value) in images {
            if let crate::episode::FeatureValue::Image(bytes) = value {
                // A PNG's bit depth is byte 24 (IHDR); TFDS declares a 16-bit one uint16.
                let format = match crate::media::image::is_jpeg(bytes) {
                    true => "jpeg",
                    false if super::record::is_tiff(bytes) => "tiff",
                    false if bytes.get(24) == Some(&16) => "png16",
                    false => "png",
                };
                (self.state.image_formats)
                    .entry(feature.name.clone())
                    .or_insert_with(|| format.into());
            }
        }
    }

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
            let (file, pending) =
                dir.create_file(&self.options.shard_path(&self.split, index, None))?;
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
        super::tfrecord::write_record(&mut shard.writer, example)
            .map_err(ExportError::io(&shard.pending.path))?;
        shard.bytes += super::tfrecord::framed_len(example.len());
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
                    self.options.shard_path(&self.split, i, None),
                    self.options.shard_path(&self.split, i, Some(count)),
                )
            })
            .collect();
        dir.rename_files(&renames, &self.state)?;
        let mut summary = self.state.summary.clone();
        let version_dir = self.options.version_dir();
        let ours = info.is_ours();
        let features = if ours {
            super::features::features_json(info, &self.options)
        } else {
            super::features::foreign_features_json(info, &self.state.image_formats)
        };
        let dataset_info = super::features::dataset_info_json(
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
            let guide = openvla_md(info, &self.options, &self.split);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::image::PngLevel;

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

    /// Another tool's `action` beside `action.gripper` (a LeRobot dataset may hold both) is
    /// refused by name before anything is written; `action_gripper` is not.
    #[test]
    fn nested_keys_of_another_tools_features_are_refused() {
        let feature = |name: &str| crate::episode::FeatureSpec {
            name: name.into(),
            dtype: crate::episode::Dtype::Float32,
            shape: vec![1],
            names: Vec::new(),
            kind: FeatureKind::Other,
            video: None,
            info: Default::default(),
        };
        let info = |names: &[&str]| {
            let features = names.iter().map(|n| feature(n)).collect();
            DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 10, "x", features)
        };
        let options = RldsOptions::default();
        let refused = RldsShards::run_options(&info(&["action", "action.gripper"]), &options)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(refused.contains("--without action.gripper"), "{refused}");
        assert!(RldsShards::run_options(&info(&["action", "action_gripper"]), &options).is_ok());
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
            options.shard_path("train", 3, None),
            "surgvla_benchmark/1.0.0/surgvla_benchmark-train.tfrecord-00003"
        );
        assert_eq!(
            options.shard_path("train", 3, Some(12)),
            "surgvla_benchmark/1.0.0/surgvla_benchmark-train.tfrecord-00003-of-00012"
        );
        assert_eq!(
            options.shard_path("val", 0, Some(1)),
            "surgvla_benchmark/1.0.0/surgvla_benchmark-val.tfrecord-00000-of-00001"
        );
    }
}
