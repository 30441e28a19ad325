//! [`DatasetInfo`]: what a dataset is, stated once and handed to every sink: its features, frame
//! rate, camera (intrinsics and `world_from_camera`), robot, mask ids and how its episodes were
//! made. A format derives its metadata files from it; a source returns one for what it read.

use crate::episode::{Aabb, CameraInfo, Dtype, FeatureKind, FeatureSpec};
use crate::export::collection::Collection;
use crate::export::dir::RunOptions;
use serde::Serialize;
use serde_json::{Value, json};

/// What a dataset is, besides its episodes.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetInfo {
    /// Control steps per second.
    pub fps: u32,
    /// LeRobot's `robot_type`.
    pub robot_type: String,
    /// The camera of every image feature.
    pub camera: CameraInfo,
    /// The features every step holds, in column order.
    pub features: Vec<FeatureSpec>,
    /// Segmentation mask id -> class name, in id order.
    pub mask_ids: Vec<(u8, String)>,
    /// How the episodes were made (seed, tasks, options), as written to `meta/surgvla.json`;
    /// None when unknown (e.g. a dataset surgvla did not write).
    pub collection: Option<Collection>,
    /// The program and version that made the episodes, e.g. "surgvla 0.1.0".
    pub generator: String,
    /// The box the robot's tool tip moves in, world frame (the default point-cloud crop, with
    /// margins); None when unknown.
    pub tip_workspace: Option<Aabb>,
    /// The identity of the dataset this one is read from ([`crate::export::identity`]), which
    /// a conversion records and its resume compares; None for a collection. Never written into
    /// a dataset, and not part of its options digest.
    pub input: Option<String>,
    /// Paragraphs (Markdown) the dataset card's "How it was made" gives of episodes made
    /// elsewhere, e.g. how `ingest` synchronised a robot's recordings; not part of the options
    /// digest.
    pub provenance: Vec<String>,
    /// Named ranges of episode indices (`train`, `val`, `recovery`, ...) as the user stated
    /// them, e.g. for Open-H; empty: every episode is `train`. Written where a format has room
    /// (LeRobot's `splits` in info.json).
    pub splits: Vec<(String, std::ops::Range<u64>)>,
    /// What reading the input decided, one line each, which a conversion prints and the card
    /// repeats: how another tool's keys were mapped (`action = steps/action/world_vector +
    /// ...`), what was left out and why. Empty for surgvla's own data; not part of the options
    /// digest.
    pub notes: Vec<String>,
    /// Features of the input its reader left out because [`crate::export::source::SourceOptions`]'s
    /// `without` named them (video surgvla cannot decode); `convert --without` takes them as
    /// done. Not part of the options digest.
    pub omitted: Vec<String>,
    /// The per-episode values another tool's dataset carries
    /// ([`crate::episode::EpisodeMeta::fields`]), declared; empty for surgvla's own data. Not
    /// part of the options digest.
    pub episode_fields: Vec<crate::episode::EpisodeField>,
    /// Keys of the dataset's description that another tool wrote and surgvla has no model for
    /// (LeRobot's info.json), carried over as they were where the format has room. Not part
    /// of the options digest.
    pub carried_keys: serde_json::Map<String, Value>,
    /// What was done to the episodes after they were made, one sentence each (an edit: what
    /// it kept, dropped, split and changed), which the card's "How it was made" lists. Not
    /// part of the options digest.
    pub history: Vec<String>,
}

/// The options a dataset's own description records (see [`DatasetInfo::run_options`]).
#[derive(Serialize)]
struct RecordedDataset<'a> {
    /// "name [shape]" per feature.
    features: Vec<String>,
    fps: u32,
    robot_type: &'a str,
    camera: CameraInfo,
    mask_ids: &'a [(u8, String)],
    generator: &'a str,
    /// Only when known, so a dataset started before the key existed still resumes.
    #[serde(skip_serializing_if = "Option::is_none")]
    tip_workspace_m: Option<Value>,
}

impl DatasetInfo {
    /// The first feature of `kind`, if the dataset has one.
    pub fn feature(&self, kind: FeatureKind) -> Option<&FeatureSpec> {
        self.features.iter().find(|f| f.kind == kind)
    }

    /// Whether the dataset has a feature of `kind`.
    pub fn has(&self, kind: FeatureKind) -> bool {
        self.feature(kind).is_some()
    }

    /// Whether `name` is a text feature ([`Dtype::String`]), which has no statistics.
    pub fn is_text(&self, name: &str) -> bool {
        (self.features.iter()).any(|f| f.name == name && f.dtype == Dtype::String)
    }

    /// Whether surgvla made the episodes (it says which program did); a dataset read from
    /// another tool's files has no generator.
    pub fn is_ours(&self) -> bool {
        !self.generator.is_empty()
    }

    /// Image (width, height) in pixels.
    pub fn image_size(&self) -> (usize, usize) {
        (
            self.camera.width_px as usize,
            self.camera.height_px as usize,
        )
    }

    /// The key of the RGB camera's feature.
    pub fn rgb_key(&self) -> Option<&str> {
        self.feature(FeatureKind::Rgb).map(|f| f.name.as_str())
    }

    /// What this dataset's bytes depend on, by option name (what a resume must give again):
    /// each key of the collection (seed, tasks, ...), the features, fps, camera, robot, mask ids
    /// and generator.
    pub fn run_options(&self) -> RunOptions {
        let mut options = RunOptions::recorded(&RecordedDataset {
            features: (self.features.iter())
                .map(|f| format!("{} {:?}", f.name, f.shape))
                .collect(),
            fps: self.fps,
            robot_type: &self.robot_type,
            camera: self.camera,
            mask_ids: &self.mask_ids,
            generator: &self.generator,
            tip_workspace_m: self.tip_workspace.map(workspace_json),
        });
        if let Some(collection) = &self.collection {
            options.merge(RunOptions::recorded(collection));
        }
        if let Some(input) = &self.input {
            options.set_input(input);
        }
        options
    }

    /// The info of a dataset read back: `surgvla` is its surgvla metadata
    /// ([`DatasetInfo::surgvla_json`]; `Value::Null` when it has none: the camera then has the
    /// images' size and unknown intrinsics).
    pub fn from_surgvla_json(
        surgvla: &Value,
        fps: u32,
        robot_type: &str,
        features: Vec<FeatureSpec>,
    ) -> Self {
        let mask_ids = surgvla["mask_ids"]
            .as_object()
            .map(|m| {
                m.iter()
                    .filter_map(|(id, name)| Some((id.parse().ok()?, name.as_str()?.to_string())))
                    .collect()
            })
            .unwrap_or_default();
        DatasetInfo {
            fps,
            robot_type: robot_type.into(),
            camera: camera_of(surgvla, &features),
            features,
            mask_ids,
            collection: Collection::from_json(&surgvla["collection"]),
            generator: surgvla["generator"].as_str().unwrap_or_default().into(),
            tip_workspace: workspace_of(&surgvla["tip_workspace_m"]),
            input: None,
            provenance: Vec::new(),
            splits: Vec::new(),
            notes: Vec::new(),
            omitted: Vec::new(),
            episode_fields: Vec::new(),
            carried_keys: Default::default(),
            history: Vec::new(),
        }
    }

    /// The surgvla metadata of a dataset (`meta/surgvla.json` in LeRobot): the camera with its
    /// intrinsics and `world_from_camera` (row-major 4x4), the depth convention, the mask id
    /// table and the collection.
    pub fn surgvla_json(&self) -> Value {
        let camera = &self.camera;
        let masks: serde_json::Map<String, Value> = self
            .mask_ids
            .iter()
            .map(|(id, name)| (id.to_string(), Value::from(name.as_str())))
            .collect();
        let mut metadata = json!({
            "generator": self.generator,
            "camera": {
                "key": self.rgb_key().unwrap_or("observation.images.endoscope"),
                "width": camera.width_px,
                "height": camera.height_px,
                "fx": camera.fx_px,
                "fy": camera.fy_px,
                "cx": camera.cx_px,
                "cy": camera.cy_px,
                "near_m": camera.near_m,
                "far_m": camera.far_m,
                "optical_frame": "x right, y down, z forward",
                "world_from_camera": camera.world_from_camera,
            },
        });
        if let Some(depth) = self.feature(FeatureKind::Depth) {
            metadata["depth"] = json!({"key": depth.name, "unit": "m", "along": "optical axis", "background": 0.0,
                  "back_projection": "X = (u + 0.5 - cx) z / fx, Y = (v + 0.5 - cy) z / fy, Z = z"});
        }
        // What another tool's dataset does not say is left out: the program (surgvla made no
        // episode of it), the intrinsics and the clipping planes.
        let camera_json = &mut metadata["camera"];
        if let Some(fields) = camera_json.as_object_mut() {
            if camera.fx_px <= 0.0 || camera.fy_px <= 0.0 {
                for key in ["fx", "fy", "cx", "cy"] {
                    fields.remove(key);
                }
            }
            if camera.near_m <= 0.0 || camera.far_m <= 0.0 {
                fields.remove("near_m");
                fields.remove("far_m");
            }
        }
        if self.generator.is_empty()
            && let Some(fields) = metadata.as_object_mut()
        {
            fields.remove("generator");
        }
        metadata["mask_ids"] = Value::Object(masks);
        if let Some(workspace) = self.tip_workspace {
            metadata["tip_workspace_m"] = workspace_json(workspace);
        }
        if let Some(collection) = &self.collection {
            metadata["collection"] = collection.to_json();
        }
        metadata
    }
}

/// The camera of surgvla metadata, or one with the images' size and unknown intrinsics.
fn camera_of(surgvla: &Value, features: &[FeatureSpec]) -> CameraInfo {
    let c = &surgvla["camera"];
    let image = features.iter().find(|f| f.dtype == Dtype::Image);
    let size = |i: usize| image.and_then(|f| f.shape.get(i)).copied().unwrap_or(0) as u32;
    let mut world_from_camera = [[0.0; 4]; 4];
    for (r, row) in world_from_camera.iter_mut().enumerate() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = c["world_from_camera"][r][k]
                .as_f64()
                .unwrap_or(if r == k { 1.0 } else { 0.0 });
        }
    }
    let number = |key: &str| c[key].as_f64().unwrap_or(0.0);
    CameraInfo {
        width_px: size(1),
        height_px: size(0),
        fx_px: number("fx"),
        fy_px: number("fy"),
        cx_px: number("cx"),
        cy_px: number("cy"),
        near_m: number("near_m"),
        far_m: number("far_m"),
        world_from_camera,
    }
}

fn workspace_json(workspace: Aabb) -> Value {
    json!({"min": workspace.min_m, "max": workspace.max_m})
}

fn workspace_of(value: &Value) -> Option<Aabb> {
    let corner = |key: &str| -> Option<[f64; 3]> {
        let values: Vec<f64> = value[key]
            .as_array()?
            .iter()
            .map(Value::as_f64)
            .collect::<Option<_>>()?;
        values.try_into().ok()
    };
    Some(Aabb {
        min_m: corner("min")?,
        max_m: corner("max")?,
    })
}
