//! The episode model: the contract between collection and every format.
//!
//! An [`Episode`] is metadata (with its provenance: seed, task, level, attempts, verdict) plus
//! [`Step`]s (images, state, action, object poses, and [`StepExtras`] the simulator knows).
//! What each feature is called, its dtype, shape and per-element names is declared once in
//! [`FeatureSpec`]s ([`standard_features`], chosen by a [`FeatureSet`]); a dataset's features
//! are part of its `DatasetInfo`, and formats and `schemas/` derive from that list. A feature a
//! dataset does not have is an empty array in its steps. Formats see episodes only, never the
//! simulator.

use serde::Serialize;

/// Largest number of movable objects whose poses `observation.environment_state` carries (a
/// target and up to three distractors).
pub const MAX_OBJECTS: usize = 4;
/// Values per object pose: x, y, z (m), qx, qy, qz, qw.
pub const POSE_VALUES: usize = 7;

/// Element type of a feature.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Dtype {
    Float32,
    /// Another tool's float64 vectors, kept as they are (surgvla's own are float32).
    Float64,
    Int64,
    /// An RGB or grey image stored as encoded bytes (PNG, or TIFF for float depth).
    Image,
    /// One UTF-8 text per step (e.g. Open-H's per-frame `instruction.text`), shape `[1]`.
    String,
}

/// What a feature holds and how it is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FeatureKind {
    /// The endoscope RGB image (u8, H x W x 3).
    Rgb,
    /// Depth, f32 metres along the optical axis (H x W x 1).
    Depth,
    /// Segmentation mask ids (u8, H x W x 1).
    Mask,
    /// The 7-D robot state.
    State,
    /// The 7-D action.
    Action,
    /// Object poses, [`MAX_OBJECTS`] x [`POSE_VALUES`], zero-padded.
    EnvironmentState,
    /// A feature surgvla has no role for (another robot's state, a second camera, ...): its
    /// values travel in [`Step::other`] unchanged, images as their encoded bytes.
    Other,
}

/// One feature of the dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureSpec {
    /// Key, e.g. "observation.state" (never contains '/').
    pub name: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// One name per element for vectors; the axis names for images.
    pub names: Vec<String>,
    pub kind: FeatureKind,
    /// An image feature its source stores as video in this codec: its frames travel encoded in
    /// [`Episode::encoded`], not as pixels in the steps (nothing here decodes video).
    pub video: Option<VideoCodec>,
    /// Facts about the feature beyond its values, kept by formats that have room for them
    /// (LeRobot: the feature's `info` in `info.json`): a pose's `frame_id`, a camera's
    /// intrinsics, a depth map's unit. Empty for most features.
    pub info: serde_json::Map<String, serde_json::Value>,
}

impl FeatureSpec {
    /// Whether the steps hold this feature's values (pixels, vectors, [`Step::other`]); a
    /// video feature's frames are in [`Episode::encoded`] instead.
    pub fn in_steps(&self) -> bool {
        self.video.is_none()
    }
}

/// A video codec.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub enum VideoCodec {
    /// AV1 (rav1e writes it; LeRobot's own codec family).
    Av1,
    /// H.264 (openh264 writes it).
    H264,
}

impl VideoCodec {
    /// The name LeRobot records in `video.codec`.
    pub fn name(self) -> &'static str {
        match self {
            VideoCodec::Av1 => "av1",
            VideoCodec::H264 => "h264",
        }
    }

    /// The quality setting surgvla encodes this codec at by default (AV1's quantizer 80,
    /// H.264's largest quantiser 22: see `media::video::VideoEncoder`).
    pub fn default_quality(self) -> u32 {
        match self {
            VideoCodec::Av1 => 80,
            VideoCodec::H264 => 22,
        }
    }

    /// The codec of a LeRobot `video.codec` name.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "av1" | "libsvtav1" | "libaom-av1" | "librav1e" => Some(VideoCodec::Av1),
            "h264" | "libx264" | "libopenh264" | "avc1" => Some(VideoCodec::H264),
            _ => None,
        }
    }
}

/// One encoded frame: H.264 as Annex B bytes, AV1 as OBUs without temporal delimiters (what the
/// MP4 muxer takes); PNG or TIFF as the file's bytes (`keyframe` true).
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedFrame {
    pub data: Vec<u8>,
    pub keyframe: bool,
}

/// How a feature's stored bytes are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageEncoding {
    /// One PNG per frame (lossless).
    Png,
    /// One float32 TIFF per frame (depth in metres).
    Tiff,
    /// One baseline JPEG per frame (lossy: RLDS RGB, as Open X-Embodiment stores it).
    Jpeg,
    /// A video stream: frames depend on earlier ones back to the last keyframe.
    Video(VideoCodec),
}

impl ImageEncoding {
    /// How surgvla stores a frame of an image feature of `kind`: depth as a float TIFF, the
    /// rest as PNG.
    pub fn of_kind(kind: FeatureKind) -> Self {
        if kind == FeatureKind::Depth {
            ImageEncoding::Tiff
        } else {
            ImageEncoding::Png
        }
    }
}

/// Statistics of a feature's pixels that its source computed (carried with video frames,
/// whose pixels nothing here decodes).
#[derive(Clone, Debug, PartialEq)]
pub enum PixelStats {
    /// The exact accumulator of the writer that saw the pixels (surgvla's own datasets), as
    /// JSON text (one JSON value; tens of kilobytes of histograms, parsed where it is merged):
    /// merging these gives the same statistics as the pixels would.
    Exact(String),
    /// LeRobot's per-episode summary (min, max, mean, std, count, quantiles), all another
    /// tool's dataset has: merged by count, quantiles approximated.
    Summary(serde_json::Value),
}

/// One image feature's frames in one episode as its source stored them, so that a sink storing
/// the same encoding copies them instead of encoding pixels again (and, for video, the only
/// form the frames have here).
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedFeature {
    /// The feature's key.
    pub feature: String,
    pub encoding: ImageEncoding,
    /// One per step (video: in decode order, the first a keyframe), unless `shown` says
    /// otherwise.
    pub frames: Vec<EncodedFrame>,
    /// The pixels' statistics, for video features.
    pub pixel_stats: Option<PixelStats>,
    /// Video whose samples are not one per step in presentation order (B-frames, frames the
    /// rows skip, a span reaching back to an earlier keyframe): each step's picture, as an
    /// index into the pictures `frames` decode to, in presentation order. Such frames can be
    /// decoded but not copied. None: frame i is step i's.
    pub shown: Option<Vec<usize>>,
    /// The file the frames were read from (for errors naming it), if any.
    pub file: Option<std::path::PathBuf>,
}

fn names(items: &[&str]) -> Vec<String> {
    items.iter().map(|s| s.to_string()).collect()
}

/// Which of the optional features a dataset has (RGB, state and action always).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FeatureSet {
    /// `observation.images.depth` (float metres).
    pub depth: bool,
    /// `observation.images.mask` (segmentation ids).
    pub mask: bool,
    /// `observation.environment_state` (ground-truth object poses).
    pub environment_state: bool,
}

impl Default for FeatureSet {
    /// The default dataset: depth and object poses, no mask.
    fn default() -> Self {
        FeatureSet {
            depth: true,
            mask: false,
            environment_state: true,
        }
    }
}

/// The features surgvla writes, in column order.
pub fn standard_features(height_px: usize, width_px: usize, set: FeatureSet) -> Vec<FeatureSpec> {
    let image = |name: &str, channels: usize, kind: FeatureKind| FeatureSpec {
        name: name.into(),
        dtype: Dtype::Image,
        shape: vec![height_px, width_px, channels],
        names: names(&["height", "width", "channels"]),
        kind,
        video: None,
        info: Default::default(),
    };
    let mut features = vec![image("observation.images.endoscope", 3, FeatureKind::Rgb)];
    if set.depth {
        features.push(image("observation.images.depth", 1, FeatureKind::Depth));
    }
    if set.mask {
        features.push(image("observation.images.mask", 1, FeatureKind::Mask));
    }
    let environment_names: Vec<String> = (0..MAX_OBJECTS)
        .flat_map(|i| {
            ["x", "y", "z", "qx", "qy", "qz", "qw"].map(move |c| format!("object_{i}.{c}"))
        })
        .collect();
    features.push(FeatureSpec {
        name: "observation.state".into(),
        dtype: Dtype::Float32,
        shape: vec![7],
        names: names(&[
            "tip_x_m",
            "tip_y_m",
            "tip_z_m",
            "tip_roll_rad",
            "tip_pitch_rad",
            "tip_yaw_rad",
            "jaw_angle_rad",
        ]),
        kind: FeatureKind::State,
        video: None,
        info: Default::default(),
    });
    if set.environment_state {
        features.push(FeatureSpec {
            name: "observation.environment_state".into(),
            dtype: Dtype::Float32,
            shape: vec![MAX_OBJECTS * POSE_VALUES],
            names: environment_names,
            kind: FeatureKind::EnvironmentState,
            video: None,
            info: Default::default(),
        });
    }
    features.push(FeatureSpec {
        name: "action".into(),
        dtype: Dtype::Float32,
        shape: vec![7],
        names: names(&[
            "dx_m",
            "dy_m",
            "dz_m",
            "droll_rad",
            "dpitch_rad",
            "dyaw_rad",
            "gripper_open",
        ]),
        kind: FeatureKind::Action,
        video: None,
        info: Default::default(),
    });
    features
}

/// How `action[6]` (the gripper) is written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GripperEncoding {
    /// The commanded state on every step: 1.0 while open, 0.0 while closed (Open
    /// X-Embodiment's convention; the default).
    #[default]
    Continuous,
    /// Opt-in for ablations: 1.0 on the step the jaws are commanded open after being closed,
    /// -1.0 on the step they are commanded closed, 0.0 otherwise (the jaws start open).
    Pulse,
}

impl GripperEncoding {
    /// The gripper values of a sequence of jaw commands (`true` = open).
    pub fn encode(self, open: &[bool]) -> Vec<f32> {
        let mut previous = true;
        open.iter()
            .map(|&now| {
                let value = match self {
                    GripperEncoding::Continuous => f32::from(u8::from(now)),
                    GripperEncoding::Pulse if now != previous => {
                        if now {
                            1.0
                        } else {
                            -1.0
                        }
                    }
                    GripperEncoding::Pulse => 0.0,
                };
                previous = now;
                value
            })
            .collect()
    }

    /// The jaw commands (`true` = open) that gripper values encode.
    pub fn decode(self, values: &[f32]) -> Vec<bool> {
        let mut state = true;
        values
            .iter()
            .map(|&v| {
                state = match self {
                    GripperEncoding::Continuous => v >= 0.5,
                    GripperEncoding::Pulse if v > 0.5 => true,
                    GripperEncoding::Pulse if v < -0.5 => false,
                    GripperEncoding::Pulse => state,
                };
                state
            })
            .collect()
    }
}

/// Pinhole intrinsics and pose of the camera that took the images.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CameraInfo {
    pub width_px: u32,
    pub height_px: u32,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    /// Clipping planes of the depth range, metres.
    pub near_m: f64,
    pub far_m: f64,
    /// Row-major 4x4 pose of the optical frame (x right, y down, z forward) in the world.
    pub world_from_camera: [[f64; 4]; 4],
}

/// An axis-aligned box in the world frame, metres.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    pub min_m: [f64; 3],
    pub max_m: [f64; 3],
}

impl Aabb {
    /// The box grown by `margin_m` on every side.
    pub fn grown(&self, margin_m: f64) -> Aabb {
        Aabb {
            min_m: self.min_m.map(|v| v - margin_m),
            max_m: self.max_m.map(|v| v + margin_m),
        }
    }

    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).all(|i| p[i] >= self.min_m[i] && p[i] <= self.max_m[i])
    }
}

/// What an episode is, besides its steps: its place, its instruction and its provenance (what
/// it takes to re-run or audit it).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EpisodeMeta {
    /// Position in the dataset, 0-based.
    pub index: u64,
    /// Task id, e.g. "T1-1".
    pub task_code: String,
    pub task_name: String,
    pub level: u8,
    /// The language instruction (the LeRobot "task" string).
    pub instruction: String,
    /// The seed of the attempt that was saved.
    pub seed: u64,
    /// Expert attempts for this slot including the saved one (1 = first try; spawn redraws
    /// not counted).
    pub attempts: u32,
    /// The task's success predicate held at the end of the episode.
    pub success: bool,
    /// Where the instruction changes during the episode (a recording whose instruction topic
    /// moves on mid-episode), in step order; empty: `instruction` holds throughout.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub task_changes: Vec<TaskChange>,
    /// Per-episode values another tool's dataset records (an RLDS dataset's
    /// `episode_metadata/file_path`, language_table's `episode_id`), by their key there, as
    /// JSON scalars or short arrays; written where a format has room (LeRobot's episodes
    /// table). Empty for surgvla's own episodes.
    #[serde(skip_serializing_if = "serde_json::Map::is_empty")]
    pub fields: serde_json::Map<String, serde_json::Value>,
}

/// A per-episode value another tool's dataset carries ([`EpisodeMeta::fields`]), declared once
/// for the dataset, so that a format with a fixed schema (RLDS's `features.json`) can state it and
/// write a default where an episode has none.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeField {
    /// Its key in [`EpisodeMeta::fields`] (RLDS: its path, e.g. `episode_metadata/file_path`).
    pub key: String,
    pub dtype: FieldDtype,
    /// Values per episode (1 for a text or a scalar).
    pub len: usize,
}

/// What an [`EpisodeField`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldDtype {
    Text,
    Int64,
    Float,
    Bool,
}

impl FieldDtype {
    /// The kind of a JSON value (a scalar or an array of them); None for nulls and objects.
    pub fn of_json(value: &serde_json::Value) -> Option<(FieldDtype, usize)> {
        use serde_json::Value;
        match value {
            Value::String(_) => Some((FieldDtype::Text, 1)),
            Value::Bool(_) => Some((FieldDtype::Bool, 1)),
            Value::Number(n) if n.is_i64() => Some((FieldDtype::Int64, 1)),
            Value::Number(_) => Some((FieldDtype::Float, 1)),
            Value::Array(items) if !items.is_empty() => {
                let kinds: Vec<FieldDtype> = (items.iter())
                    .map(|v| FieldDtype::of_json(v).filter(|k| k.1 == 1).map(|k| k.0))
                    .collect::<Option<_>>()?;
                // Numbers are floats if any is; texts are one per key.
                let numbers = kinds
                    .iter()
                    .all(|k| matches!(k, FieldDtype::Int64 | FieldDtype::Float));
                let dtype = if numbers && kinds.contains(&FieldDtype::Float) {
                    FieldDtype::Float
                } else if kinds.iter().all(|k| *k == kinds[0]) && kinds[0] != FieldDtype::Text {
                    kinds[0]
                } else {
                    return None;
                };
                Some((dtype, items.len()))
            }
            _ => None,
        }
    }
}

/// From step `first_step` of an episode on, its instruction is `instruction`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TaskChange {
    pub first_step: u64,
    pub instruction: String,
}

impl EpisodeMeta {
    /// The meta of an episode surgvla's experts did not make (another tool's dataset, a robot
    /// recording): no task id, seed or attempts, success unknown (false).
    pub fn foreign(index: u64, instruction: String) -> EpisodeMeta {
        EpisodeMeta {
            index,
            task_code: String::new(),
            task_name: String::new(),
            level: 0,
            instruction,
            seed: 0,
            attempts: 0,
            success: false,
            task_changes: Vec::new(),
            fields: serde_json::Map::new(),
        }
    }

    /// The instruction of step `step`: the last change at or before it, else `instruction`.
    pub fn instruction_at(&self, step: usize) -> &str {
        (self.task_changes.iter())
            .rev()
            .find(|c| c.first_step <= step as u64)
            .map_or(&self.instruction, |c| &c.instruction)
    }

    /// The episode's instructions, each once, in the order they first hold.
    pub fn instructions(&self) -> Vec<&str> {
        let mut all = vec![self.instruction.as_str()];
        for change in &self.task_changes {
            if !all.contains(&change.instruction.as_str()) {
                all.push(&change.instruction);
            }
        }
        all
    }

    /// The changes of per-step instructions (`instruction` being step 0's): one per step whose
    /// instruction differs from the step before.
    pub fn changes_of<'a>(per_step: impl IntoIterator<Item = &'a str>) -> Vec<TaskChange> {
        let mut changes = Vec::new();
        let mut previous: Option<&str> = None;
        for (step, instruction) in per_step.into_iter().enumerate() {
            if previous.is_some_and(|p| p != instruction) {
                changes.push(TaskChange {
                    first_step: step as u64,
                    instruction: instruction.to_string(),
                });
            }
            previous = Some(instruction);
        }
        changes
    }
}

/// One control step.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    /// RGB u8, row-major H x W x 3.
    pub rgb: Vec<u8>,
    /// Depth f32 metres, row-major H x W; 0 where nothing is in range.
    pub depth_m: Vec<f32>,
    /// Mask ids, row-major H x W.
    pub mask: Vec<u8>,
    pub state: [f32; 7],
    pub action: [f32; 7],
    /// [`MAX_OBJECTS`] x [`POSE_VALUES`], zero-padded.
    pub environment_state: [f32; MAX_OBJECTS * POSE_VALUES],
    /// What the simulator knew besides the features (empty when read from a dataset).
    pub extras: StepExtras,
    /// The values of the dataset's [`FeatureKind::Other`] features held in steps
    /// ([`FeatureSpec::in_steps`]), in feature order.
    pub other: Vec<FeatureValue>,
}

/// A step's image buffers, taken out of it (see [`Step::take_pixels`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pixels {
    pub rgb: Vec<u8>,
    pub depth_m: Vec<f32>,
    pub mask: Vec<u8>,
}

impl Step {
    /// Takes the step's RGB, depth and mask out of it (leaving them empty).
    pub fn take_pixels(&mut self) -> Pixels {
        Pixels {
            rgb: std::mem::take(&mut self.rgb),
            depth_m: std::mem::take(&mut self.depth_m),
            mask: std::mem::take(&mut self.mask),
        }
    }

    /// A step holding nothing yet (readers fill in what their dataset has).
    pub fn empty() -> Step {
        Step {
            rgb: Vec::new(),
            depth_m: Vec::new(),
            mask: Vec::new(),
            state: [0.0; 7],
            action: [0.0; 7],
            environment_state: [0.0; MAX_OBJECTS * POSE_VALUES],
            extras: StepExtras::default(),
            other: Vec::new(),
        }
    }
}

/// One step's value of a [`FeatureKind::Other`] feature.
#[derive(Clone, Debug, PartialEq)]
pub enum FeatureValue {
    Float32(Vec<f32>),
    Float64(Vec<f64>),
    Int64(Vec<i64>),
    /// An encoded image (PNG or JPEG), passed through as stored.
    Image(Vec<u8>),
    /// A [`Dtype::String`] feature's text.
    Text(String),
}

/// Per-step facts the simulator knows beyond the dataset features, for formats that have room
/// for them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepExtras {
    /// PSM joint positions before the step (rad; the insertion joint in m).
    pub joint_positions: Vec<f64>,
    /// The object held by the jaws before the step.
    pub held_object: Option<String>,
    /// The object the jaws grasped during the step.
    pub grasped: Option<String>,
    /// The object the jaws released during the step.
    pub released: Option<String>,
    /// Whether the task's success predicate held after the step (None: unknown, e.g. read from
    /// a dataset).
    pub success_after: Option<bool>,
    /// The robot's frames in the world before the step (`psm_rcm`, `psm_link_1..`, `psm_shaft`,
    /// `psm_jaw_pivot`).
    pub frames: Vec<NamedPose>,
}

/// A named pose in the world frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedPose {
    pub name: String,
    pub position_m: [f64; 3],
    /// Unit quaternion (x, y, z, w).
    pub rotation_xyzw: [f64; 4],
}

/// One triangle mesh of a scene, for viewers: its vertices are in `frame`, which is `world`, a
/// movable object's `object_<i>` (scene order) or an instrument frame of [`StepExtras::frames`],
/// so it moves with that frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneMesh {
    pub name: String,
    pub frame: String,
    /// Linear RGB, 0..1.
    pub rgb: [f32; 3],
    pub positions_m: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// An episode's rows as a file of its source stores them, for a sink writing the same format
/// to copy them as stored instead of encoding the steps again (LeRobot: a data file's row
/// group, its column chunks copied compressed). The steps lack the pixels of the image features
/// in the stored rows ([`StoredRows::holds_pixels`]): only such a sink can write the episode.
#[derive(Clone)]
pub struct StoredRows {
    /// (its column's key in the stored rows, the feature's key now) of every feature the
    /// stored rows hold: a feature renamed since keeps its stored column.
    pub columns: Vec<(String, String)>,
    /// The format's own description of where the rows are (downcast by its sink).
    pub handle: std::sync::Arc<dyn std::any::Any + Send + Sync>,
}

impl StoredRows {
    /// The stored column of feature `name` (its key now).
    pub fn column_of(&self, name: &str) -> Option<&str> {
        (self.columns.iter())
            .find(|(_, now)| now == name)
            .map(|(stored, _)| stored.as_str())
    }

    /// Whether feature `name`'s pixels are in the stored rows only (an image feature the rows
    /// hold).
    pub fn holds_pixels(&self, feature: &FeatureSpec) -> bool {
        feature.dtype == Dtype::Image
            && feature.in_steps()
            && self.column_of(&feature.name).is_some()
    }
}

impl std::fmt::Debug for StoredRows {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StoredRows")
            .field("columns", &self.columns)
            .finish_non_exhaustive()
    }
}

impl PartialEq for StoredRows {
    fn eq(&self, other: &Self) -> bool {
        self.columns == other.columns && std::sync::Arc::ptr_eq(&self.handle, &other.handle)
    }
}

/// A recorded episode.
#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    pub meta: EpisodeMeta,
    pub steps: Vec<Step>,
    /// Image features' frames as the source stored them (empty for a fresh recording): every
    /// video feature's, and PNG / TIFF bytes a reader already had beside the decoded pixels.
    pub encoded: Vec<EncodedFeature>,
    /// Per image feature held in the steps as encoded bytes, the exact statistics accumulator
    /// of its pixels over the episode, when the source had the pixels before it encoded them
    /// (a recording ingested): a writer takes it instead of decoding every image again.
    /// Empty for most sources.
    pub image_stats: Vec<(String, PixelStats)>,
    /// The rows as the source's file stores them, when the source was asked to leave them
    /// there (an edit writing the input's format): see [`StoredRows`]. None for most sources.
    pub stored_rows: Option<StoredRows>,
}

impl Episode {
    /// Checks that the episode has steps, video frames for its video features and the other
    /// features' values in every step: all but the sizes of the steps' RGB, depth and mask
    /// ([`Episode::validate_pixels`]; an encoder that checked them may have taken the pixels).
    pub fn validate_structure(&self, features: &[FeatureSpec]) -> Result<(), String> {
        if self.steps.is_empty() {
            return Err(format!("episode {} has no steps", self.meta.index));
        }
        let others: Vec<&FeatureSpec> = features
            .iter()
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
            .collect();
        for feature in features.iter().filter(|f| !f.in_steps()) {
            let frames = self
                .encoded_video(&feature.name)
                .map_or(0, |e| e.frames.len());
            if frames != self.steps.len() {
                return Err(format!(
                    "episode {}: {} has {frames} video frames for {} steps",
                    self.meta.index,
                    feature.name,
                    self.steps.len()
                ));
            }
            if self
                .encoded_video(&feature.name)
                .and_then(|e| e.frames.first())
                .is_some_and(|f| !f.keyframe)
            {
                return Err(format!(
                    "episode {}: {} does not start on a keyframe",
                    self.meta.index, feature.name
                ));
            }
        }
        for (i, step) in self.steps.iter().enumerate() {
            if step.other.len() != others.len() {
                return Err(format!(
                    "episode {} step {i}: {} values of other features where the dataset has {}",
                    self.meta.index,
                    step.other.len(),
                    others.len()
                ));
            }
            for (feature, value) in others.iter().zip(&step.other) {
                let elements: usize = feature.shape.iter().product();
                let fits = match (feature.dtype, value) {
                    (Dtype::Float32, FeatureValue::Float32(v)) => v.len() == elements,
                    (Dtype::Float64, FeatureValue::Float64(v)) => v.len() == elements,
                    (Dtype::Int64, FeatureValue::Int64(v)) => v.len() == elements,
                    (Dtype::Image, FeatureValue::Image(bytes)) => !bytes.is_empty(),
                    (Dtype::String, FeatureValue::Text(_)) => elements == 1,
                    _ => false,
                };
                if !fits {
                    return Err(format!(
                        "episode {} step {i}: {} does not hold a {:?} of shape {:?}",
                        self.meta.index, feature.name, feature.dtype, feature.shape
                    ));
                }
            }
        }
        Ok(())
    }

    /// That every step holds each image feature of `features` kept in the steps (RGB, depth,
    /// mask) with the size of a `width_px` x `height_px` image.
    pub fn validate_pixels(
        &self,
        width_px: usize,
        height_px: usize,
        features: &[FeatureSpec],
    ) -> Result<(), String> {
        // Pixels left in the stored rows are the sink's to copy, not the steps'.
        let in_steps: Vec<FeatureSpec>;
        let features = match &self.stored_rows {
            Some(stored) => {
                in_steps = (features.iter())
                    .filter(|f| !stored.holds_pixels(f))
                    .cloned()
                    .collect();
                &in_steps[..]
            }
            None => features,
        };
        for (i, step) in self.steps.iter().enumerate() {
            step_pixels_fit(step, width_px, height_px, features)
                .map_err(|problem| format!("episode {} step {i}: {problem}", self.meta.index))?;
        }
        Ok(())
    }

    /// The stored frames of `feature` in `encoding`, if the source kept them.
    pub fn encoded_as(&self, feature: &str, encoding: ImageEncoding) -> Option<&EncodedFeature> {
        self.encoded
            .iter()
            .find(|e| e.feature == feature && e.encoding == encoding)
    }

    /// The frames of `feature` in `encoding`, one per step, if the source kept them.
    pub fn stored_frames(&self, feature: &str, encoding: ImageEncoding) -> Option<&[EncodedFrame]> {
        self.encoded_as(feature, encoding)
            .filter(|e| e.frames.len() == self.steps.len())
            .map(|e| e.frames.as_slice())
    }

    /// The PNG bytes of `feature`, one per step, if the source kept them.
    pub fn stored_png(&self, feature: &str) -> Option<&[EncodedFrame]> {
        self.stored_frames(feature, ImageEncoding::Png)
    }

    /// The video frames of `feature`, if it arrived as video.
    pub fn encoded_video(&self, feature: &str) -> Option<&EncodedFeature> {
        self.encoded
            .iter()
            .find(|e| e.feature == feature && matches!(e.encoding, ImageEncoding::Video(_)))
    }
}

/// Whether `step` holds each image feature of `features` kept in the steps with the size of a
/// `width_px` x `height_px` image (the problem otherwise).
pub fn step_pixels_fit(
    step: &Step,
    width_px: usize,
    height_px: usize,
    features: &[FeatureSpec],
) -> Result<(), String> {
    let pixels = width_px * height_px;
    for feature in features.iter().filter(|f| f.in_steps()) {
        let (what, len, expected) = match feature.kind {
            FeatureKind::Rgb => ("rgb", step.rgb.len(), pixels * 3),
            FeatureKind::Depth => ("depth", step.depth_m.len(), pixels),
            FeatureKind::Mask => ("mask", step.mask.len(), pixels),
            _ => continue,
        };
        if len != expected {
            return Err(format!(
                "{what} has {len} values where a {width_px}x{height_px} image has {expected}"
            ));
        }
    }
    Ok(())
}

/// An episode of no steps, `index` of task T1-1 with seed `seed`: what the sources tests make
/// give.
#[cfg(test)]
pub(crate) fn empty_episode(index: u64, seed: u64) -> Episode {
    Episode {
        meta: EpisodeMeta {
            index,
            task_code: "T1-1".into(),
            task_name: "gauze_pick".into(),
            level: 1,
            instruction: String::new(),
            seed,
            attempts: 1,
            success: true,
            task_changes: Vec::new(),
            fields: serde_json::Map::new(),
        },
        steps: Vec::new(),
        encoded: Vec::new(),
        image_stats: Vec::new(),
        stored_rows: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn features_have_unique_slash_free_names_and_one_name_per_element() {
        let all = FeatureSet {
            mask: true,
            ..FeatureSet::default()
        };
        let features = standard_features(224, 224, all);
        let mut seen = std::collections::HashSet::new();
        for feature in &features {
            assert!(!feature.name.contains('/'));
            assert!(seen.insert(feature.name.clone()));
            if feature.dtype == Dtype::Float32 {
                assert_eq!(feature.names.len(), feature.shape[0], "{}", feature.name);
            }
        }
        assert_eq!(
            standard_features(224, 224, FeatureSet::default()).len(),
            features.len() - 1
        );
        let lean = FeatureSet {
            depth: false,
            mask: false,
            environment_state: false,
        };
        let kinds: Vec<FeatureKind> = standard_features(224, 224, lean)
            .iter()
            .map(|f| f.kind)
            .collect();
        assert_eq!(
            kinds,
            [FeatureKind::Rgb, FeatureKind::State, FeatureKind::Action]
        );
    }

    #[test]
    fn gripper_encodings_round_trip_and_differ() {
        let open = [true, true, false, false, false, true, true, false];
        for encoding in [GripperEncoding::Continuous, GripperEncoding::Pulse] {
            assert_eq!(encoding.decode(&encoding.encode(&open)), open);
        }
        assert_eq!(
            GripperEncoding::Continuous.encode(&open),
            [1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0]
        );
        assert_eq!(
            GripperEncoding::Pulse.encode(&open),
            [0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, -1.0]
        );
    }
}
