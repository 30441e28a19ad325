//! One step as Foxglove messages: the endoscope image (CompressedImage, PNG), depth (RawImage,
//! 32FC1 metres), its calibration (CameraCalibration), the point cloud (PointCloud: x y z
//! float32 and r g b a uint8, stride 16, world frame), the frames (FrameTransforms: world to the
//! endoscope's optical frame, to the tool tip from the state, to each object from the object
//! poses), and the robot's state and action as JSON. Everything comes from the episode and the
//! `DatasetInfo`.

use crate::episode::{CameraInfo, MAX_OBJECTS, POSE_VALUES, SceneMesh, Step};
use crate::export::pointcloud::Cloud;
use foxglove::messages::{
    CameraCalibration, Color, CompressedImage, FrameTransform, FrameTransforms, PackedElementField,
    Point3, PointCloud, Pose, Quaternion, RawImage, SceneEntity, SceneUpdate, Timestamp,
    TriangleListPrimitive, Vector3, packed_element_field::NumericType,
};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
use serde_json::{Value, json};

/// The world frame's id.
pub const WORLD: &str = "world";
/// The endoscope's optical frame (x right, y down, z forward): the images' frame.
pub const OPTICAL: &str = "endoscope_optical";
/// The tool tip's frame, from the state.
pub const TOOL_TIP: &str = "tool_tip";

/// Nanoseconds as a Foxglove timestamp.
pub fn timestamp(ns: u64) -> Timestamp {
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn transform(
    ns: u64,
    child: &str,
    translation: [f64; 3],
    rotation: UnitQuaternion<f64>,
) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(ns)),
        parent_frame_id: WORLD.into(),
        child_frame_id: child.into(),
        translation: Some(Vector3 {
            x: translation[0],
            y: translation[1],
            z: translation[2],
        }),
        rotation: Some(Quaternion {
            x: rotation.i,
            y: rotation.j,
            z: rotation.k,
            w: rotation.w,
        }),
    }
}

pub fn compressed_image(ns: u64, png: Vec<u8>) -> CompressedImage {
    CompressedImage {
        timestamp: Some(timestamp(ns)),
        frame_id: OPTICAL.into(),
        data: png.into(),
        format: "png".into(),
    }
}

pub fn depth_image(ns: u64, camera: &CameraInfo, depth_m: &[f32]) -> RawImage {
    RawImage {
        timestamp: Some(timestamp(ns)),
        frame_id: OPTICAL.into(),
        width: camera.width_px,
        height: camera.height_px,
        encoding: "32FC1".into(),
        step: camera.width_px * 4,
        data: depth_m
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>()
            .into(),
    }
}

/// The calibration in Foxglove's (ROS's) convention, where pixel centres sit on integer
/// coordinates: our principal point (pixel centres at +0.5) moves by half a pixel.
pub fn calibration(ns: u64, camera: &CameraInfo) -> CameraCalibration {
    let (fx, fy) = (camera.fx_px, camera.fy_px);
    let (cx, cy) = (camera.cx_px - 0.5, camera.cy_px - 0.5);
    CameraCalibration {
        timestamp: Some(timestamp(ns)),
        frame_id: OPTICAL.into(),
        width: camera.width_px,
        height: camera.height_px,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

/// The cloud's real points, world frame.
pub fn point_cloud(ns: u64, cloud: &Cloud) -> PointCloud {
    let field = |name: &str, offset: u32, kind: NumericType| PackedElementField {
        name: name.into(),
        offset,
        r#type: kind as i32,
    };
    let mut data = Vec::with_capacity(cloud.valid * 16);
    for i in 0..cloud.valid {
        for v in cloud.xyz_m[i] {
            data.extend_from_slice(&v.to_le_bytes());
        }
        data.extend_from_slice(&cloud.rgb[i]);
        data.push(255);
    }
    PointCloud {
        timestamp: Some(timestamp(ns)),
        frame_id: WORLD.into(),
        // The points are in the world frame already: the identity pose, stated (converters such
        // as rerun's MCAP import require it).
        pose: Some(Pose {
            position: Some(Vector3 {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            }),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
        point_stride: 16,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("red", 12, NumericType::Uint8),
            field("green", 13, NumericType::Uint8),
            field("blue", 14, NumericType::Uint8),
            field("alpha", 15, NumericType::Uint8),
        ],
        data: data.into(),
    }
}

/// World -> optical frame, -> tool tip (state: x y z, Euler xyz with R = Rz Ry Rx), -> each
/// object with a pose (named by `objects`).
pub fn frames(
    ns: u64,
    camera: &CameraInfo,
    step: &Step,
    objects: &[String],
    with_tip: bool,
) -> FrameTransforms {
    let m = &camera.world_from_camera;
    let rotation = Matrix3::from_fn(|r, c| m[r][c]);
    let optical = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&rotation));
    let mut transforms = vec![transform(ns, OPTICAL, [m[0][3], m[1][3], m[2][3]], optical)];
    if with_tip {
        let s = step.state.map(f64::from);
        let tip = UnitQuaternion::from_euler_angles(s[3], s[4], s[5]);
        transforms.push(transform(ns, TOOL_TIP, [s[0], s[1], s[2]], tip));
    }
    for (i, name) in objects.iter().enumerate().take(MAX_OBJECTS) {
        let pose = &step.environment_state[i * POSE_VALUES..(i + 1) * POSE_VALUES];
        if pose.iter().all(|&v| v == 0.0) {
            continue;
        }
        let p = pose.iter().map(|&v| f64::from(v)).collect::<Vec<_>>();
        let rotation =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(p[6], p[3], p[4], p[5]));
        transforms.push(transform(ns, name, [p[0], p[1], p[2]], rotation));
    }
    for frame in &step.extras.frames {
        let [x, y, z, w] = frame.rotation_xyzw;
        let rotation = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        transforms.push(transform(ns, &frame.name, frame.position_m, rotation));
    }
    FrameTransforms { transforms }
}

/// The scene's meshes as one SceneUpdate: an entity per mesh, locked to its frame, so objects
/// and the instrument move with their `/tf` frames.
pub fn scene_update(ns: u64, meshes: &[SceneMesh]) -> SceneUpdate {
    let entities = meshes
        .iter()
        .map(|mesh| SceneEntity {
            timestamp: Some(timestamp(ns)),
            frame_id: mesh.frame.clone(),
            id: mesh.name.clone(),
            lifetime: None,
            frame_locked: true,
            metadata: Vec::new(),
            arrows: Vec::new(),
            cubes: Vec::new(),
            spheres: Vec::new(),
            cylinders: Vec::new(),
            lines: Vec::new(),
            triangles: vec![TriangleListPrimitive {
                pose: None,
                points: mesh
                    .positions_m
                    .iter()
                    .map(|p| Point3 {
                        x: f64::from(p[0]),
                        y: f64::from(p[1]),
                        z: f64::from(p[2]),
                    })
                    .collect(),
                color: Some(Color {
                    r: f64::from(mesh.rgb[0]),
                    g: f64::from(mesh.rgb[1]),
                    b: f64::from(mesh.rgb[2]),
                    a: 1.0,
                }),
                colors: Vec::new(),
                indices: mesh.triangles.iter().flatten().copied().collect(),
            }],
            texts: Vec::new(),
            models: Vec::new(),
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// `/robot/state` as JSON.
pub fn state_json(ns: u64, step: &Step) -> Value {
    let s = step.state;
    json!({
        "timestamp_ns": ns,
        "tip_position_m": [s[0], s[1], s[2]],
        "tip_euler_xyz_rad": [s[3], s[4], s[5]],
        "jaw_angle_rad": s[6],
        "held_object": step.extras.held_object,
        "joint_positions": step.extras.joint_positions,
        "grasped": step.extras.grasped,
        "released": step.extras.released,
        "success_so_far": step.extras.success_after,
    })
}

/// A feature surgvla has no role for (another tool's), as JSON: its numbers (NaN as null), or
/// its text; None for an image (a compressed image message of its own).
pub fn feature_json(ns: u64, value: &crate::episode::FeatureValue) -> Option<Value> {
    use crate::episode::FeatureValue;
    Some(match value {
        FeatureValue::Float32(values) => json!({"timestamp_ns": ns, "values": values}),
        FeatureValue::Float64(values) => json!({"timestamp_ns": ns, "values": values}),
        FeatureValue::Int64(values) => json!({"timestamp_ns": ns, "values": values}),
        FeatureValue::Text(text) => json!({"timestamp_ns": ns, "text": text}),
        FeatureValue::Image(_) => return None,
    })
}

/// The JSON Schema of [`feature_json`]'s messages of `feature`: its length and element names.
pub fn feature_schema(feature: &crate::episode::FeatureSpec) -> Value {
    use crate::episode::Dtype;
    let value = match feature.dtype {
        Dtype::String => json!({"text": {"type": "string"}}),
        dtype => {
            let element = if dtype == Dtype::Int64 {
                json!({"type": "integer"})
            } else {
                json!({"type": ["number", "null"], "description": "null: not a number"})
            };
            let length = feature.shape.iter().product::<usize>();
            let mut values =
                json!({"type": "array", "items": element, "minItems": length, "maxItems": length});
            if !feature.names.is_empty() {
                values["description"] = json!(format!("elements: {}", feature.names.join(", ")));
            }
            json!({"values": values})
        }
    };
    let mut properties = json!({"timestamp_ns": {"type": "integer"}});
    if let (Some(all), Some(more)) = (properties.as_object_mut(), value.as_object()) {
        all.extend(more.clone());
    }
    let required: Vec<&String> = properties
        .as_object()
        .map(|p| p.keys().collect())
        .unwrap_or_default();
    json!({
        "title": format!("surgvla.Feature {}", feature.name),
        "type": "object",
        "properties": properties,
        "required": required,
    })
}

/// An image feature surgvla has no role for, as stored (JPEG or PNG bytes).
pub fn stored_image(ns: u64, key: &str, bytes: &[u8]) -> CompressedImage {
    let format = if crate::media::image::is_jpeg(bytes) {
        "jpeg"
    } else {
        "png"
    };
    CompressedImage {
        timestamp: Some(timestamp(ns)),
        frame_id: key.into(),
        data: bytes.to_vec().into(),
        format: format.into(),
    }
}

/// `/robot/action` as JSON.
pub fn action_json(ns: u64, step: &Step) -> Value {
    let a = step.action;
    json!({
        "timestamp_ns": ns,
        "delta_position_m": [a[0], a[1], a[2]],
        "delta_euler_xyz_rad": [a[3], a[4], a[5]],
        "gripper_open": a[6],
    })
}

/// The JSON schemas of the JSON channels.
pub fn state_schema() -> Value {
    let vector =
        json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3});
    json!({
        "title": "surgvla.RobotState",
        "type": "object",
        "properties": {
            "timestamp_ns": {"type": "integer"},
            "tip_position_m": vector,
            "tip_euler_xyz_rad": vector,
            "jaw_angle_rad": {"type": "number"},
            "held_object": {"type": ["string", "null"]},
            "joint_positions": {"type": "array", "items": {"type": "number"}, "description": "PSM joints (rad; the insertion joint in m); empty when converted from a dataset"},
            "grasped": {"type": ["string", "null"], "description": "the object the jaws grasped during the step"},
            "released": {"type": ["string", "null"], "description": "the object the jaws released during the step"},
            "success_so_far": {"type": ["boolean", "null"], "description": "the task's success predicate after the step (null when converted from a dataset)"},
        },
        "required": ["timestamp_ns", "tip_position_m", "tip_euler_xyz_rad", "jaw_angle_rad"],
    })
}

pub fn action_schema() -> Value {
    let vector =
        json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3});
    json!({
        "title": "surgvla.RobotAction",
        "type": "object",
        "properties": {
            "timestamp_ns": {"type": "integer"},
            "delta_position_m": vector,
            "delta_euler_xyz_rad": vector,
            "gripper_open": {"type": "number", "description": "1 = open, 0 = closed"},
        },
        "required": ["timestamp_ns", "delta_position_m", "delta_euler_xyz_rad", "gripper_open"],
    })
}

pub fn info_schema() -> Value {
    json!({
        "title": "surgvla.EpisodeInfo",
        "type": "object",
        "properties": {
            "episode_index": {"type": "integer"},
            "task_id": {"type": "string"},
            "level": {"type": "integer"},
            "seed": {"type": "integer"},
            "instruction": {"type": "string"},
            "success": {"type": "boolean"},
            "frames": {"type": "integer"},
            "fields": {"type": "object", "description": "another tool's per-episode values, as read"},
        },
        "required": ["episode_index", "instruction", "frames"],
    })
}

/// The JSON Schemas of the JSON channels, by topic (`schemas/mcap_json_channels.json`).
pub fn json_channel_schemas() -> Value {
    serde_json::json!({
        "/robot/state": state_schema(),
        "/robot/action": action_schema(),
        "/episode/info": info_schema(),
    })
}
