//! The MCAP writer: [`McapWriter`] records each episode as one MCAP file (images, depth, point
//! cloud, frames, state, action on Foxglove's schemas) and [`record_episode`] writes one alone.

use crate::episode::{Episode, FeatureKind, SceneMesh};
use crate::export::dir::{DatasetDir, RunOptions};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::pointcloud::{CloudSettings, RecordedCloud, frame_cloud};
use crate::export::sink::Summary;
use crate::export::writer::{EpisodeEncoder, EpisodeFiles, FormatWriter, Writer};
use crate::media::image::{PngLevel, encode_png, stored_or};
use foxglove::Encode;
use rayon::prelude::*;
use serde_json::{Value, json};
use std::collections::BTreeMap;

/// The recordings' time origin: 2024-01-01T00:00:00Z in nanoseconds.
pub const T0_NS: u64 = 1_704_067_200_000_000_000;

/// Episodes between checkpoints.
pub const CHECKPOINT_EPISODES: u64 = 16;

/// Every file with its size and CRC-32C.
pub const MANIFEST: &str = "surgvla_manifest.json";

/// Options of the MCAP recordings.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct McapOptions {
    /// How `/endoscope/points` clouds are made.
    pub cloud: CloudSettings,
}

impl McapOptions {
    pub fn run_options(&self) -> RunOptions {
        /// The options an MCAP dataset records.
        #[derive(serde::Serialize)]
        struct Recorded {
            format: &'static str,
            #[serde(flatten)]
            cloud: RecordedCloud,
        }
        RunOptions::recorded(&Recorded {
            format: "mcap",
            cloud: self.cloud.recorded(),
        })
    }
}

pub(super) fn mcap_error(what: &str) -> impl FnOnce(mcap::McapError) -> ExportError + '_ {
    move |source| ExportError::Encode {
        what: format!("MCAP {what}"),
        source: Box::new(source),
    }
}

/// MCAP's part of [`McapWriter`].
pub struct McapFiles {
    options: McapOptions,
    state: EpisodeFiles,
}

/// A message type's schema added to a writer.
fn schema_of<T: Encode>(
    writer: &mut mcap::Writer<std::io::Cursor<Vec<u8>>>,
) -> Result<u16, ExportError> {
    let schema = T::get_schema()
        .ok_or_else(|| ExportError::Internal("a Foxglove type without a schema".into()))?;
    writer
        .add_schema(&schema.name, &schema.encoding, &schema.data)
        .map_err(mcap_error("schema"))
}

fn encoded<T: Encode>(message: &T) -> Result<Vec<u8>, ExportError> {
    let mut bytes = Vec::with_capacity(message.encoded_len().unwrap_or(1024));
    message
        .encode(&mut bytes)
        .map_err(|e| ExportError::Encode {
            what: "a Foxglove message".into(),
            source: Box::new(std::io::Error::other(e.to_string())),
        })?;
    Ok(bytes)
}

/// A writer into memory as every episode's file is written: zstd chunks compressed on this
/// thread, no profile, `library` in the header.
pub(super) fn new_writer(
    library: &str,
) -> Result<mcap::Writer<std::io::Cursor<Vec<u8>>>, ExportError> {
    mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .profile("")
        .library(library)
        .create(std::io::Cursor::new(Vec::new()))
        .map_err(mcap_error("writer"))
}

/// The episode's provenance as the recording's first metadata record.
fn write_provenance(
    writer: &mut mcap::Writer<std::io::Cursor<Vec<u8>>>,
    info: &DatasetInfo,
    meta: &crate::episode::EpisodeMeta,
) -> Result<(), ExportError> {
    let mut provenance: BTreeMap<String, String> = [
        ("episode_index", meta.index.to_string()),
        ("instruction", meta.instruction.clone()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    // Provenance only where surgvla made the episode.
    if info.is_ours() {
        provenance.extend(
            [
                ("task_id", meta.task_code.clone()),
                ("level", meta.level.to_string()),
                ("seed", meta.seed.to_string()),
                ("success", meta.success.to_string()),
                ("generator", info.generator.clone()),
            ]
            .map(|(k, v)| (k.to_string(), v)),
        );
    }
    writer
        .write_metadata(&mcap::records::Metadata {
            name: "episode".into(),
            metadata: provenance,
        })
        .map_err(mcap_error("metadata"))?;
    Ok(())
}

/// What a step's messages are made with.
struct StepMessages<'a> {
    info: &'a DatasetInfo,
    channels: &'a Channels,
    cloud_options: Option<&'a crate::export::pointcloud::CloudOptions>,
    /// The frame names of the objects' poses.
    objects: Vec<String>,
    /// The source's PNG bytes of the RGB frames, copied instead of encoded again.
    stored_rgb: Option<&'a [crate::episode::EncodedFrame]>,
}

impl StepMessages<'_> {
    /// Step `t`'s messages at `ns`, channel by channel, in the order they are written.
    fn of(
        &self,
        t: usize,
        ns: u64,
        step: &crate::episode::Step,
    ) -> Result<Vec<(u16, Vec<u8>)>, ExportError> {
        let (camera, channels) = (&self.info.camera, self.channels);
        let (width, height) = self.info.image_size();
        let png = stored_or(self.stored_rgb, t, || {
            encode_png(width, height, 3, &step.rgb, PngLevel::Fast)
        })?;
        let mut out = vec![(
            channels.rgb,
            encoded(&super::messages::compressed_image(ns, png))?,
        )];
        if let Some(channel) = channels.depth {
            out.push((
                channel,
                encoded(&super::messages::depth_image(ns, camera, &step.depth_m))?,
            ));
        }
        if let Some(channel) = channels.calibration {
            out.push((channel, encoded(&super::messages::calibration(ns, camera))?));
        }
        if let (Some(channel), Some(cloud_options)) = (channels.points, self.cloud_options) {
            let cloud = frame_cloud(camera, step, cloud_options);
            out.push((channel, encoded(&super::messages::point_cloud(ns, &cloud))?));
        }
        let tf = super::messages::frames(ns, camera, step, &self.objects, channels.state.is_some());
        out.push((channels.tf, encoded(&tf)?));
        if let Some(channel) = channels.state {
            let json = super::messages::state_json(ns, step);
            out.push((channel, json.to_string().into_bytes()));
        }
        if let Some(channel) = channels.action {
            let json = super::messages::action_json(ns, step);
            out.push((channel, json.to_string().into_bytes()));
        }
        for ((channel, key), value) in channels.features.iter().zip(&step.other) {
            let data = match super::messages::feature_json(ns, value) {
                Some(json) => json.to_string().into_bytes(),
                None => match value {
                    crate::episode::FeatureValue::Image(bytes) => {
                        encoded(&super::messages::stored_image(ns, key, bytes))?
                    }
                    _ => continue,
                },
            };
            out.push((*channel, data));
        }
        Ok(out)
    }
}

/// An episode recording's channels (ids), added with their schemas in a fixed order.
struct Channels {
    info: u16,
    rgb: u16,
    depth: Option<u16>,
    /// With the camera's intrinsics.
    calibration: Option<u16>,
    points: Option<u16>,
    tf: u16,
    scene: Option<u16>,
    /// With surgvla's state and action.
    state: Option<u16>,
    action: Option<u16>,
    /// Per feature without a role (another tool's), in the order of the steps' values: its
    /// channel and key.
    features: Vec<(u16, String)>,
}

impl Channels {
    /// Adds the schemas, then the channels: depth with the depth feature, points `with_points`,
    /// the scene's meshes `with_scene`.
    fn add(
        writer: &mut mcap::Writer<std::io::Cursor<Vec<u8>>>,
        info: &DatasetInfo,
        with_points: bool,
        with_scene: bool,
    ) -> Result<Self, ExportError> {
        let no_metadata = BTreeMap::new();
        let rgb_schema = schema_of::<foxglove::messages::CompressedImage>(writer)?;
        let depth_schema = schema_of::<foxglove::messages::RawImage>(writer)?;
        let calibration_schema = schema_of::<foxglove::messages::CameraCalibration>(writer)?;
        let points_schema = schema_of::<foxglove::messages::PointCloud>(writer)?;
        let tf_schema = schema_of::<foxglove::messages::FrameTransforms>(writer)?;
        let scene_schema = (with_scene)
            .then(|| schema_of::<foxglove::messages::SceneUpdate>(writer))
            .transpose()?;
        let json_schemas = [
            (super::messages::state_schema(), "surgvla.RobotState"),
            (super::messages::action_schema(), "surgvla.RobotAction"),
            (super::messages::info_schema(), "surgvla.EpisodeInfo"),
        ]
        .map(|(value, name): (Value, &str)| {
            writer
                .add_schema(name, "jsonschema", value.to_string().as_bytes())
                .map_err(mcap_error("schema"))
        });
        let [state_schema, action_schema, info_schema] = json_schemas;
        let (state_schema, action_schema, info_schema) =
            (state_schema?, action_schema?, info_schema?);
        let mut add = |schema: u16, topic: &str, encoding: &str| {
            writer
                .add_channel(schema, topic, encoding, &no_metadata)
                .map_err(mcap_error("channel"))
        };
        let mut add_if = |wanted: bool, schema: u16, topic: &str, encoding: &str| {
            wanted.then(|| add(schema, topic, encoding)).transpose()
        };
        let (protobuf, json) = ("protobuf", "json");
        let info_channel = add_if(true, info_schema, "/episode/info", json)?;
        let rgb = add_if(true, rgb_schema, "/endoscope/rgb", protobuf)?;
        let depth = add_if(
            info.has(FeatureKind::Depth),
            depth_schema,
            "/endoscope/depth",
            protobuf,
        )?;
        let calibration = add_if(
            info.camera.fx_px > 0.0,
            calibration_schema,
            "/endoscope/camera_info",
            protobuf,
        )?;
        let points = add_if(with_points, points_schema, "/endoscope/points", protobuf)?;
        let tf = add_if(true, tf_schema, "/tf", protobuf)?;
        let scene_channel = match scene_schema {
            Some(schema) => add_if(true, schema, "/scene", protobuf)?,
            None => None,
        };
        let state = add_if(
            info.has(FeatureKind::State),
            state_schema,
            "/robot/state",
            json,
        )?;
        let action = add_if(
            info.has(FeatureKind::Action),
            action_schema,
            "/robot/action",
            json,
        )?;
        let features = feature_channels(writer, info, rgb_schema)?;
        let (Some(info_channel), Some(rgb), Some(tf)) = (info_channel, rgb, tf) else {
            return Err(ExportError::Internal("a channel added is missing".into()));
        };
        Ok(Channels {
            info: info_channel,
            rgb,
            depth,
            calibration,
            points,
            tf,
            scene: scene_channel,
            state,
            action,
            features,
        })
    }
}

/// The channels of the features without a role (another tool's), after every other channel:
/// a JSON Schema of each vector or text, images on `image_schema` (a compressed image as
/// stored); each channel with its feature's key.
fn feature_channels(
    writer: &mut mcap::Writer<std::io::Cursor<Vec<u8>>>,
    info: &DatasetInfo,
    image_schema: u16,
) -> Result<Vec<(u16, String)>, ExportError> {
    let others = (info.features.iter()).filter(|f| f.kind == FeatureKind::Other && f.in_steps());
    let mut channels = Vec::new();
    for feature in others {
        let (schema, encoding) = match feature.dtype {
            crate::episode::Dtype::Image => (image_schema, "protobuf"),
            _ => {
                let schema = super::messages::feature_schema(feature).to_string();
                let id = writer
                    .add_schema("surgvla.Feature", "jsonschema", schema.as_bytes())
                    .map_err(mcap_error("schema"))?;
                (id, "json")
            }
        };
        let topic = feature_topic(&feature.name);
        let channel = writer
            .add_channel(schema, &topic, encoding, &BTreeMap::new())
            .map_err(mcap_error("channel"))?;
        channels.push((channel, feature.name.clone()));
    }
    Ok(channels)
}

/// The topic of a feature without a role: its key with dots as slashes
/// (`observation.images.wrist` on `/observation/images/wrist`).
fn feature_topic(key: &str) -> String {
    format!("/{}", key.replace('.', "/"))
}

/// The MCAP file of one episode; `scene`, when given, goes on `/scene` once at the start (the
/// simulator's recorder has it, a dataset does not).
pub fn record_episode(
    info: &DatasetInfo,
    options: &McapOptions,
    episode: &Episode,
    scene: Option<&[SceneMesh]>,
) -> Result<Vec<u8>, ExportError> {
    let cloud_options = points_options(info, options)?;
    let mut writer = new_writer(&info.generator)?;
    let meta = &episode.meta;
    write_provenance(&mut writer, info, meta)?;
    let channels = Channels::add(&mut writer, info, cloud_options.is_some(), scene.is_some())?;
    let steps = StepMessages {
        info,
        channels: &channels,
        cloud_options: cloud_options.as_ref(),
        objects: (0..crate::episode::MAX_OBJECTS)
            .map(|i| format!("object_{i}"))
            .collect(),
        stored_rgb: info.rgb_key().and_then(|key| episode.stored_png(key)),
    };
    // Per step, encoded in parallel: every message's bytes.
    let fps = u64::from(info.fps.max(1));
    let step_messages: Vec<Vec<(u16, Vec<u8>)>> = episode
        .steps
        .par_iter()
        .enumerate()
        .map(|(t, step)| steps.of(t, T0_NS + t as u64 * 1_000_000_000 / fps, step))
        .collect::<Result<_, _>>()?;
    let (info_channel, scene_channel) = (channels.info, channels.scene);
    let mut info_message = json!({
        "episode_index": meta.index,
        "instruction": meta.instruction,
        "frames": episode.steps.len(),
    });
    // Provenance only where surgvla made the episode; another tool's values as read.
    if info.is_ours() {
        info_message["task_id"] = json!(meta.task_code);
        info_message["level"] = json!(meta.level);
        info_message["seed"] = json!(meta.seed);
        info_message["success"] = json!(meta.success);
    }
    if !meta.fields.is_empty() {
        info_message["fields"] = Value::Object(meta.fields.clone());
    }
    let mut sequence = 0u32;
    let mut write = |writer: &mut mcap::Writer<_>, channel: u16, ns: u64, data: &[u8]| {
        sequence += 1;
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence,
                    log_time: ns,
                    publish_time: ns,
                },
                data,
            )
            .map_err(mcap_error("message"))
    };
    write(
        &mut writer,
        info_channel,
        T0_NS,
        info_message.to_string().as_bytes(),
    )?;
    if let (Some(channel), Some(meshes)) = (scene_channel, scene) {
        let update = encoded(&super::messages::scene_update(T0_NS, meshes))?;
        write(&mut writer, channel, T0_NS, &update)?;
    }
    for (t, messages) in step_messages.iter().enumerate() {
        let ns = T0_NS + t as u64 * 1_000_000_000 / fps;
        for (channel, data) in messages {
            write(&mut writer, *channel, ns, data)?;
        }
    }
    writer.finish().map_err(mcap_error("summary"))?;
    Ok(writer.into_inner().into_inner())
}

/// How `/endoscope/points` clouds are made; None without them: a dataset without depth, or
/// another tool's without intrinsics (`convert --intrinsics`) or a crop box (`--crop`).
fn points_options(
    info: &DatasetInfo,
    options: &McapOptions,
) -> Result<Option<crate::export::pointcloud::CloudOptions>, ExportError> {
    let unknown =
        info.camera.fx_px <= 0.0 || (info.tip_workspace.is_none() && options.cloud.crop.is_none());
    if !info.has(FeatureKind::Depth) || unknown {
        return Ok(None);
    }
    options.cloud.options(info).map(Some)
}

/// Writes one MCAP file per episode.
pub type McapWriter = Writer<McapFiles>;

impl FormatWriter for McapFiles {
    type Options = McapOptions;
    type State = EpisodeFiles;
    type Encoded = Vec<u8>;
    type Encoder<'a> = (&'a Self, &'a DatasetInfo);
    const MANIFEST: &'static str = MANIFEST;

    fn card_format(&self) -> crate::export::card::CardFormat {
        crate::export::card::CardFormat {
            name: "mcap",
            tagged: true,
            data_files: None,
            loading: None,
            depth: "Recorded as 32FC1 images in metres.",
            video: Vec::new(),
        }
    }

    fn run_options(info: &DatasetInfo, options: &McapOptions) -> Result<RunOptions, ExportError> {
        points_options(info, options)?;
        let mut run = info.run_options();
        run.merge(options.run_options());
        Ok(run)
    }

    fn owned_folders(_: &McapOptions) -> Vec<String> {
        vec![String::new()]
    }

    fn new(
        _: &DatasetDir,
        _: &DatasetInfo,
        options: McapOptions,
        state: Option<EpisodeFiles>,
    ) -> Result<Self, ExportError> {
        Ok(McapFiles {
            options,
            state: state.unwrap_or_default(),
        })
    }

    fn episodes(&self) -> u64 {
        self.state.episodes()
    }

    /// Only the RGB camera's PNG bytes are copied into its messages.
    fn reuses_stored(&self, encoding: crate::episode::ImageEncoding) -> bool {
        encoding == crate::episode::ImageEncoding::Png
    }

    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> (&'a Self, &'a DatasetInfo) {
        (self, info)
    }

    fn append(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        episode: &Episode,
        bytes: Vec<u8>,
    ) -> Result<f64, ExportError> {
        let file = format!("episode_{:06}.mcap", episode.meta.index);
        self.state.write_file(dir, &file, &bytes)?;
        self.state.episode_done(
            dir,
            episode,
            Some(&file),
            CHECKPOINT_EPISODES,
            info.is_ours(),
        )?;
        Ok(0.0)
    }

    fn finish(&mut self, dir: &mut DatasetDir, _: &DatasetInfo) -> Result<Summary, ExportError> {
        self.state.finish(dir, "episodes.jsonl")
    }
}

impl EpisodeEncoder<Vec<u8>> for (&McapFiles, &DatasetInfo) {
    fn encode(&self, episode: &Episode) -> Result<Vec<u8>, ExportError> {
        let (format, info) = *self;
        record_episode(info, &format.options, episode, None)
    }
}
