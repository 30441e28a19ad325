//! What a frame's features are made of, taken from decoded messages ([`RosValue`]): header
//! stamps and frames, poses (`PoseStamped`, `TransformStamped`, `Pose`, `Transform`) as
//! [x, y, z, qx, qy, qz, qw], joint positions, RGB images from `sensor_msgs/Image` (rgb8, bgr8,
//! mono8 replicated, rgba8 / bgra8 without alpha; the row `step` honoured) and
//! `sensor_msgs/CompressedImage` (JPEG, PNG; ROS's format strings such as `rgb8; jpeg
//! compressed bgr8`), and depth from 16UC1 (millimetres) and 32FC1 (metres) images. An encoding
//! surgvla does not convert (Bayer, YUV, ...) is refused by name; sizes are checked against the
//! bytes before anything is allocated.

use crate::ingest::decode::RosValue;

/// An 8-bit RGB image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    /// Row-major RGB, `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

/// A depth image in whole millimetres (0: no depth), as a 16-bit PNG keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    pub width: usize,
    pub height: usize,
    pub depth_mm: Vec<u16>,
}

/// The largest raw image read, in pixels.
pub const MAX_PIXELS: usize = 8192 * 8192;

/// A message's `header.stamp`, ns.
pub fn stamp_ns(message: &RosValue) -> Option<i64> {
    message.at("header.stamp")?.as_time_ns()
}

/// A message's `header.frame_id`.
pub fn frame_id(message: &RosValue) -> Option<&str> {
    message.at("header.frame_id")?.as_str()
}

/// The most characters of a frame or model name kept (a forged one cannot swell info.json).
const MAX_NAME_CHARS: usize = 256;

/// The most values of a `CameraInfo` matrix kept.
const MAX_MATRIX_VALUES: usize = 64;

/// What a `sensor_msgs/CameraInfo` states of its camera, as a feature's `info` keys:
/// `camera.frame_id`, `camera.width`, `camera.height`, `camera.distortion_model` and the
/// matrices `camera.k` (3x3), `camera.d`, `camera.r` (3x3) and `camera.p` (3x4), row-major
/// (ROS 1 spells them `K`, `D`, `R`, `P`).
pub fn camera_intrinsics(message: &RosValue) -> serde_json::Map<String, serde_json::Value> {
    use serde_json::{Value, json};
    let mut info = serde_json::Map::new();
    if let Some(frame) = frame_id(message) {
        info.insert(
            "camera.frame_id".into(),
            json!(frame.chars().take(MAX_NAME_CHARS).collect::<String>()),
        );
    }
    for key in ["width", "height"] {
        if let Some(v) = message.field(key).and_then(RosValue::as_i64) {
            info.insert(format!("camera.{key}"), json!(v));
        }
    }
    if let Some(model) = message.field("distortion_model").and_then(RosValue::as_str) {
        info.insert(
            "camera.distortion_model".into(),
            json!(model.chars().take(MAX_NAME_CHARS).collect::<String>()),
        );
    }
    for key in ["k", "d", "r", "p"] {
        let field = (message.field(key)).or_else(|| message.field(&key.to_uppercase()));
        // A matrix of a recording is short (D has 5 to 14 values); a longer one is cut, so a
        // forged message cannot swell info.json.
        if let Some(RosValue::Array(values)) = field {
            let numbers: Vec<Value> = (values.iter().take(MAX_MATRIX_VALUES))
                .filter_map(RosValue::as_f64)
                .filter(|v| v.is_finite())
                .map(|v| json!(v))
                .collect();
            info.insert(format!("camera.{key}"), Value::Array(numbers));
        }
    }
    info
}

/// A pose's frames as a feature's `info` keys for `arm`: `ARM.frame_id` (its header's) and,
/// for a `TransformStamped`, `ARM.child_frame_id`.
pub fn pose_frames(arm: &str, message: &RosValue) -> Vec<(String, serde_json::Value)> {
    let mut out = Vec::new();
    let mut keep = |key: String, name: Option<&str>| {
        if let Some(name) = name.filter(|n| !n.is_empty()) {
            out.push((
                key,
                name.chars().take(MAX_NAME_CHARS).collect::<String>().into(),
            ));
        }
    };
    keep(format!("{arm}.frame_id"), frame_id(message));
    let child = message.field("child_frame_id").and_then(RosValue::as_str);
    keep(format!("{arm}.child_frame_id"), child);
    out
}

/// A pose as [x, y, z, qx, qy, qz, qw] (metres, unit quaternion as recorded).
pub fn pose7(message: &RosValue) -> Result<[f64; 7], String> {
    let (position, orientation) = if let Some(pose) = message.field("pose") {
        (pose.field("position"), pose.field("orientation"))
    } else if let Some(transform) = message.field("transform") {
        (transform.field("translation"), transform.field("rotation"))
    } else if message.field("position").is_some() {
        (message.field("position"), message.field("orientation"))
    } else {
        (message.field("translation"), message.field("rotation"))
    };
    let (Some(p), Some(q)) = (position, orientation) else {
        return Err("is not a pose (PoseStamped, TransformStamped, Pose or Transform)".into());
    };
    let mut out = [0.0; 7];
    for (slot, (value, name)) in out.iter_mut().zip([
        (p, "x"),
        (p, "y"),
        (p, "z"),
        (q, "x"),
        (q, "y"),
        (q, "z"),
        (q, "w"),
    ]) {
        *slot = value
            .field(name)
            .and_then(RosValue::as_f64)
            .ok_or_else(|| format!("a pose without its {name}"))?;
    }
    Ok(out)
}

/// A `JointState`'s positions, in order.
pub fn joint_positions(message: &RosValue) -> Result<Vec<f64>, String> {
    match message.field("position") {
        Some(RosValue::Array(values)) => values
            .iter()
            .map(|v| {
                v.as_f64()
                    .ok_or_else(|| "a position that is not a number".into())
            })
            .collect(),
        _ => Err("is not a JointState (no position list)".into()),
    }
}

fn uint(message: &RosValue, name: &str) -> Result<usize, String> {
    message
        .field(name)
        .and_then(RosValue::as_i64)
        .and_then(|v| usize::try_from(v).ok())
        .ok_or_else(|| format!("an image without its {name}"))
}

fn data(message: &RosValue) -> Result<&[u8], String> {
    match message.field("data") {
        Some(RosValue::Bytes(bytes)) => Ok(bytes),
        _ => Err("an image without its data".into()),
    }
}

/// A raw image's size, encoding, row step and data, checked against each other.
fn raw(message: &RosValue, bytes_per_pixel: usize) -> Result<(usize, usize, usize, &[u8]), String> {
    let (width, height, step) = (
        uint(message, "width")?,
        uint(message, "height")?,
        uint(message, "step")?,
    );
    if width == 0 || height == 0 || width.saturating_mul(height) > MAX_PIXELS {
        return Err(format!("a {width}x{height} image"));
    }
    let data = data(message)?;
    if step < width * bytes_per_pixel || data.len() < step.saturating_mul(height) {
        return Err(format!(
            "a {width}x{height} image with row step {step} and {} bytes of data",
            data.len()
        ));
    }
    Ok((width, height, step, data))
}

/// The RGB pixels of a `sensor_msgs/Image`.
pub fn raw_rgb(message: &RosValue) -> Result<RgbImage, String> {
    let encoding = message
        .field("encoding")
        .and_then(RosValue::as_str)
        .ok_or("an image without its encoding")?;
    let (channels, order): (usize, [usize; 3]) = match encoding {
        "rgb8" => (3, [0, 1, 2]),
        "bgr8" => (3, [2, 1, 0]),
        "rgba8" => (4, [0, 1, 2]),
        "bgra8" => (4, [2, 1, 0]),
        "mono8" | "8UC1" => (1, [0, 0, 0]),
        other => {
            return Err(format!(
                "image encoding {other:?} is not one surgvla converts to RGB (rgb8, bgr8, rgba8, bgra8, mono8)"
            ));
        }
    };
    let (width, height, step, data) = raw(message, channels)?;
    let mut rgb = Vec::with_capacity(width * height * 3);
    for row in data.chunks(step).take(height) {
        let row = &row[..width * channels];
        if encoding == "rgb8" {
            // Already RGB: the row as it is.
            rgb.extend_from_slice(row);
            continue;
        }
        for pixel in row.chunks_exact(channels) {
            rgb.extend(order.map(|c| pixel[c]));
        }
    }
    Ok(RgbImage { width, height, rgb })
}

/// The depth of a `sensor_msgs/Image` in millimetres: 16UC1 (and mono16) as recorded, exactly;
/// 32FC1 (metres) rounded to the millimetre, with no depth (NaN, infinite, zero or negative) and
/// depth beyond 65.535 m as 0.
pub fn raw_depth(message: &RosValue) -> Result<DepthImage, String> {
    let encoding = message
        .field("encoding")
        .and_then(RosValue::as_str)
        .ok_or("an image without its encoding")?;
    let big = message
        .field("is_bigendian")
        .and_then(RosValue::as_i64)
        .is_some_and(|b| b != 0);
    let size = match encoding {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => {
            return Err(format!(
                "depth encoding {other:?} is not 16UC1 (mm) or 32FC1 (m)"
            ));
        }
    };
    let (width, height, step, data) = raw(message, size)?;
    let metres = |m: f32| {
        let mm = (f64::from(m) * 1000.0).round();
        if mm.is_finite() && mm > 0.0 && mm <= f64::from(u16::MAX) {
            mm as u16
        } else {
            0
        }
    };
    let mut depth_mm = Vec::with_capacity(width * height);
    for row in data.chunks(step).take(height) {
        for sample in row[..width * size].chunks_exact(size) {
            depth_mm.push(match *sample {
                [a, b] if big => u16::from_be_bytes([a, b]),
                [a, b] => u16::from_le_bytes([a, b]),
                [a, b, c, d] if big => metres(f32::from_be_bytes([a, b, c, d])),
                [a, b, c, d] => metres(f32::from_le_bytes([a, b, c, d])),
                _ => 0,
            });
        }
    }
    Ok(DepthImage {
        width,
        height,
        depth_mm,
    })
}

/// A camera message's pixels as RGB: a `sensor_msgs/CompressedImage` (it has a `format`) or a
/// raw `sensor_msgs/Image`.
pub fn rgb(message: &RosValue) -> Result<RgbImage, String> {
    if message.field("format").is_some() {
        compressed_rgb(message)
    } else {
        raw_rgb(message)
    }
}

/// The RGB pixels of a `sensor_msgs/CompressedImage` (JPEG or PNG; the bytes say which, the
/// format string must agree; `bgr8; jpeg compressed bgr8` is ROS's name for an ordinary
/// colour JPEG).
pub fn compressed_rgb(message: &RosValue) -> Result<RgbImage, String> {
    let format = message
        .field("format")
        .and_then(RosValue::as_str)
        .unwrap_or_default()
        .to_ascii_lowercase();
    let bytes = data(message)?;
    let is_jpeg = crate::media::image::is_jpeg(bytes);
    let named = |name: &str| format.is_empty() || format.contains(name);
    let (width, height, channels, pixels) = if is_jpeg && named("jpeg") {
        crate::media::image::decode_jpeg(bytes)?
    } else if bytes.starts_with(b"\x89PNG") && named("png") {
        crate::media::image::decode_png(bytes)?
    } else {
        return Err(format!(
            "a compressed image of format {format:?} that is not a JPEG or PNG"
        ));
    };
    let (width, height) = (width as usize, height as usize);
    let rgb = match channels {
        3 => pixels,
        1 => pixels.iter().flat_map(|&g| [g, g, g]).collect(),
        4 => pixels
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        other => return Err(format!("a compressed image of {other} channels")),
    };
    Ok(RgbImage { width, height, rgb })
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::ingest::fixtures::message;

    #[test]
    fn camera_info_in_either_spelling_and_pose_frames_become_feature_info() {
        let floats = |v: &[f64]| RosValue::Array(v.iter().map(|&x| RosValue::Float(x)).collect());
        let header = message(vec![("frame_id", RosValue::String("left_optical".into()))]);
        for (k, d) in [("K", "D"), ("k", "d")] {
            let info = camera_intrinsics(&message(vec![
                ("header", header.clone()),
                ("height", RosValue::UInt(480)),
                ("width", RosValue::UInt(640)),
                ("distortion_model", RosValue::String("plumb_bob".into())),
                (d, floats(&[0.1, f64::NAN])),
                (
                    k,
                    floats(&[500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]),
                ),
            ]));
            assert_eq!(info["camera.frame_id"], "left_optical");
            assert_eq!(
                (
                    info["camera.width"].as_i64(),
                    info["camera.height"].as_i64()
                ),
                (Some(640), Some(480))
            );
            assert_eq!(info["camera.k"][2], 320.0);
            assert_eq!(
                info["camera.d"],
                serde_json::json!([0.1]),
                "non-finite values left out"
            );
            assert!(!info.contains_key("camera.p"));
        }
        let long = camera_intrinsics(&message(vec![
            ("d", floats(&[0.5; 100])),
            ("distortion_model", RosValue::String("x".repeat(1000))),
        ]));
        assert_eq!(long["camera.d"].as_array().map(Vec::len), Some(64), "cut");
        assert_eq!(
            long["camera.distortion_model"].as_str().map(str::len),
            Some(256)
        );
        let transform = message(vec![
            (
                "header",
                message(vec![("frame_id", RosValue::String("PSM1_base".into()))]),
            ),
            ("child_frame_id", RosValue::String("PSM1_tip".into())),
        ]);
        let frames = pose_frames("PSM1", &transform);
        assert_eq!(frames[0], ("PSM1.frame_id".to_string(), "PSM1_base".into()));
        assert_eq!(
            frames[1],
            ("PSM1.child_frame_id".to_string(), "PSM1_tip".into())
        );
        assert!(pose_frames("PSM1", &message(vec![])).is_empty());
    }

    fn image(encoding: &str, width: u64, height: u64, step: u64, data: Vec<u8>) -> RosValue {
        message(vec![
            ("height", RosValue::UInt(height)),
            ("width", RosValue::UInt(width)),
            ("encoding", RosValue::String(encoding.into())),
            ("is_bigendian", RosValue::UInt(0)),
            ("step", RosValue::UInt(step)),
            ("data", RosValue::Bytes(data)),
        ])
    }

    #[test]
    fn raw_images_in_every_encoding_with_padded_rows() {
        // 2x2, rows padded to 8 bytes.
        let bgr = vec![1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0];
        let image_bgr = raw_rgb(&image("bgr8", 2, 2, 8, bgr)).expect("bgr8");
        assert_eq!(image_bgr.rgb, [3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10]);
        let mono = raw_rgb(&image("mono8", 2, 1, 2, vec![5, 9])).expect("mono8");
        assert_eq!(mono.rgb, [5, 5, 5, 9, 9, 9]);
        let error = raw_rgb(&image("bayer_rggb8", 2, 1, 2, vec![5, 9])).expect_err("bayer");
        assert!(error.contains("bayer_rggb8"), "{error}");
        let short = raw_rgb(&image("rgb8", 2, 2, 6, vec![0; 11])).expect_err("short");
        assert!(short.contains("11 bytes"), "{short}");
        let huge = raw_rgb(&image("rgb8", 1 << 20, 1 << 20, 3 << 20, Vec::new()));
        assert!(huge.is_err());
        let depth = raw_depth(&image("16UC1", 2, 1, 4, vec![0xe9, 0x03, 0, 0])).expect("16UC1");
        assert_eq!(depth.depth_mm, [1001, 0]);
        let metres: Vec<u8> = [1.0016f32, f32::NAN, -1.0, 70.0]
            .iter()
            .flat_map(|m| m.to_le_bytes())
            .collect();
        let depth = raw_depth(&image("32FC1", 4, 1, 16, metres)).expect("32FC1");
        assert_eq!(
            depth.depth_mm,
            [1002, 0, 0, 0],
            "rounded; no depth and too far as 0"
        );
        let error = raw_depth(&image("rgb8", 1, 1, 3, vec![0; 3])).expect_err("rgb8");
        assert!(error.contains("\"rgb8\""), "{error}");
    }

    #[test]
    fn poses_of_either_message_type() {
        let xyz = |x, y, z| {
            message(vec![
                ("x", RosValue::Float(x)),
                ("y", RosValue::Float(y)),
                ("z", RosValue::Float(z)),
            ])
        };
        let q = message(vec![
            ("x", RosValue::Float(0.0)),
            ("y", RosValue::Float(0.0)),
            ("z", RosValue::Float(0.0)),
            ("w", RosValue::Float(1.0)),
        ]);
        let stamped = message(vec![(
            "pose",
            message(vec![
                ("position", xyz(1.0, 2.0, 3.0)),
                ("orientation", q.clone()),
            ]),
        )]);
        let transform = message(vec![(
            "transform",
            message(vec![("translation", xyz(1.0, 2.0, 3.0)), ("rotation", q)]),
        )]);
        let want = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0];
        assert_eq!(pose7(&stamped), Ok(want));
        assert_eq!(pose7(&transform), Ok(want));
        assert!(pose7(&message(vec![])).is_err());
    }

    #[test]
    fn compressed_png_and_jpeg() {
        let rgb: Vec<u8> = (0..4 * 2 * 3).map(|i| (i * 10) as u8).collect();
        let png =
            crate::media::image::encode_png(4, 2, 3, &rgb, crate::media::image::PngLevel::Fast)
                .expect("png");
        let compressed = |format: &str, bytes: Vec<u8>| {
            message(vec![
                ("format", RosValue::String(format.into())),
                ("data", RosValue::Bytes(bytes)),
            ])
        };
        let image = compressed_rgb(&compressed("png", png.clone())).expect("png");
        assert_eq!((image.width, image.height, image.rgb), (4, 2, rgb.clone()));
        let jpeg = crate::media::image::encode_jpeg(4, 2, &rgb, 90).expect("jpeg");
        let image = compressed_rgb(&compressed("rgb8; jpeg compressed bgr8", jpeg)).expect("jpeg");
        assert_eq!((image.width, image.height), (4, 2));
        assert!(
            compressed_rgb(&compressed("jpeg", png)).is_err(),
            "PNG bytes named JPEG"
        );
        assert!(compressed_rgb(&compressed("png", vec![1, 2, 3])).is_err());
    }
}
