//! One episode as one `tf.train.Example` and back. Per-step values are concatenated over the
//! steps under `steps/...` keys (the step count is implicit and must agree across keys);
//! provenance goes under `episode_metadata/...`. Images are PNG: RGB 3-channel uint8, depth
//! 1-channel uint16 in millimetres, mask 1-channel uint8.

use crate::episode::{
    Dtype, EncodedFeature, EncodedFrame, Episode, EpisodeMeta, FeatureKind, FeatureValue,
    ImageEncoding, MAX_OBJECTS, POSE_VALUES, Step, TaskChange,
};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::rlds::example::{Feature, decode_example, encode_example};
use crate::export::rlds::options::RldsKeys;
use crate::media::image::{
    PngLevel, decode_jpeg_sized, decode_png_sized, decode_png16_sized, encode_jpeg, encode_png,
    encode_png16, is_jpeg, stored_or,
};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Depth in metres as the uint16 millimetres RLDS stores (rounded; 0 stays 0, beyond 65.535 m
/// saturates).
pub fn depth_to_mm(depth_m: f32) -> u16 {
    if depth_m.is_finite() && depth_m > 0.0 {
        (f64::from(depth_m) * 1000.0)
            .round()
            .min(f64::from(u16::MAX)) as u16
    } else {
        0
    }
}

/// What the steps of a dataset hold: its image size and which optional features it has,
/// under which observation keys.
#[derive(Clone, Debug, PartialEq)]
pub struct StepLayout {
    pub keys: RldsKeys,
    pub width_px: usize,
    pub height_px: usize,
    pub depth: bool,
    pub mask: bool,
    pub environment_state: bool,
    /// The dataset's RGB and mask feature names: PNG bytes an episode brings for them are
    /// copied rather than encoded again.
    pub png_features: [Option<String>; 2],
    /// Writing: the RGB camera as JPEG of this quality instead of PNG (JPEG bytes an episode
    /// brings are copied). Reading takes either.
    pub jpeg_quality: Option<u8>,
}

impl StepLayout {
    pub fn of(info: &DatasetInfo, keys: &RldsKeys) -> Self {
        let (width_px, height_px) = info.image_size();
        StepLayout {
            keys: keys.clone(),
            width_px,
            height_px,
            depth: info.has(FeatureKind::Depth),
            mask: info.has(FeatureKind::Mask),
            environment_state: info.has(FeatureKind::EnvironmentState),
            png_features: [FeatureKind::Rgb, FeatureKind::Mask]
                .map(|kind| info.feature(kind).map(|f| f.name.clone())),
            jpeg_quality: None,
        }
    }

    fn observation(key: &str) -> String {
        format!("steps/observation/{key}")
    }
}

/// The id `episode_metadata/file_path` holds: "T1-1/seed-123" (or "episode-7" without a task).
pub fn file_path(meta: &EpisodeMeta) -> String {
    if meta.task_code.is_empty() {
        format!("episode-{}", meta.index)
    } else {
        format!("{}/seed-{}", meta.task_code, meta.seed)
    }
}

/// The encoded images of one step.
struct StepImages {
    rgb: Vec<u8>,
    depth: Option<Vec<u8>>,
    mask: Option<Vec<u8>>,
}

fn text(value: &str) -> Feature {
    Feature::Bytes(vec![value.as_bytes().to_vec()])
}

/// One feature's values over an episode of another tool's dataset, as RLDS stores them.
fn foreign_feature(
    feature: &crate::episode::FeatureSpec,
    position: usize,
    episode: &Episode,
) -> Result<Feature, ExportError> {
    let steps = &episode.steps;
    let wrong = || {
        ExportError::InvalidEpisode(format!(
            "episode {}: {} does not hold {:?} values",
            episode.meta.index, feature.name, feature.dtype
        ))
    };
    let first_image = match steps.first().and_then(|s| s.other.get(position)) {
        Some(FeatureValue::Image(bytes)) => Some(bytes.as_slice()),
        _ => None,
    };
    Ok(match feature.dtype {
        // A float image (TIFF) of another tool's: RLDS has no float image type, and it is not
        // necessarily depth in metres, so its values are a float32 tensor of its shape.
        Dtype::Image if first_image.is_some_and(is_tiff) => {
            tiff_tensor(feature, position, episode)?
        }
        Dtype::Image => Feature::Bytes(
            steps
                .iter()
                .map(|s| match s.other.get(position) {
                    Some(FeatureValue::Image(bytes)) => Ok(bytes.clone()),
                    _ => Err(wrong()),
                })
                .collect::<Result<_, _>>()?,
        ),
        Dtype::Float32 => {
            let mut flat = Vec::new();
            for step in steps {
                match step.other.get(position) {
                    Some(FeatureValue::Float32(v)) => flat.extend_from_slice(v),
                    _ => return Err(wrong()),
                }
            }
            Feature::Float(flat)
        }
        // TFRecord's floats are float32, as tensorflow_datasets stores float64 tensors.
        Dtype::Float64 => {
            let mut flat = Vec::new();
            for step in steps {
                match step.other.get(position) {
                    Some(FeatureValue::Float64(v)) => flat.extend(v.iter().map(|&x| x as f32)),
                    _ => return Err(wrong()),
                }
            }
            Feature::Float(flat)
        }
        Dtype::Int64 => {
            let mut flat = Vec::new();
            for step in steps {
                match step.other.get(position) {
                    Some(FeatureValue::Int64(v)) => flat.extend_from_slice(v),
                    _ => return Err(wrong()),
                }
            }
            Feature::Int64(flat)
        }
        Dtype::String => Feature::Bytes(
            steps
                .iter()
                .map(|step| match step.other.get(position) {
                    Some(FeatureValue::Text(text)) => Ok(text.as_bytes().to_vec()),
                    _ => Err(wrong()),
                })
                .collect::<Result<_, _>>()?,
        ),
    })
}

/// The serialized Example of an episode of a dataset another tool made (features all
/// [`FeatureKind::Other`](crate::episode::FeatureKind::Other)): each feature under
/// Every step's `language_instruction` (see [`EpisodeMeta::instruction_at`]).
fn step_instructions(meta: &EpisodeMeta, steps: usize) -> Feature {
    Feature::Bytes(
        (0..steps)
            .map(|step| meta.instruction_at(step).as_bytes().to_vec())
            .collect(),
    )
}

/// The first step's instruction and its changes, from every step's `language_instruction`.
fn step_instructions_read(texts: &[Vec<u8>]) -> Result<(String, Vec<TaskChange>), String> {
    let texts = (texts.iter())
        .map(|t| std::str::from_utf8(t))
        .collect::<Result<Vec<&str>, _>>()
        .map_err(|_| "steps/language_instruction is not UTF-8".to_string())?;
    let changes = EpisodeMeta::changes_of(texts.iter().copied());
    Ok((
        texts.first().copied().unwrap_or_default().to_string(),
        changes,
    ))
}

/// `steps/<its rlds_path>` as stored (images byte for byte), the instruction on every step,
/// `is_first` / `is_last` / `is_terminal` (the last step), `episode_metadata/file_path`.
pub fn encode_foreign_episode(
    info: &DatasetInfo,
    episode: &Episode,
) -> Result<Vec<u8>, ExportError> {
    let steps = &episode.steps;
    let last = steps.len().saturating_sub(1);
    let mut features = BTreeMap::new();
    for (position, feature) in info.features.iter().enumerate() {
        let key = format!(
            "steps/{}",
            crate::export::rlds::options::rlds_path(&feature.name).join("/")
        );
        let value = foreign_feature(feature, position, episode)?;
        features.insert(key, value);
    }
    features.insert(
        "steps/language_instruction".into(),
        step_instructions(&episode.meta, steps.len()),
    );
    let flags = |on: &dyn Fn(usize) -> bool| {
        Feature::Int64((0..steps.len()).map(|i| i64::from(on(i))).collect())
    };
    features.insert("steps/is_first".into(), flags(&|i| i == 0));
    features.insert("steps/is_last".into(), flags(&|i| i == last));
    features.insert("steps/is_terminal".into(), flags(&|i| i == last));
    if !metadata_taken(info) {
        features.insert(
            "episode_metadata/file_path".into(),
            text(&format!("episode-{}", episode.meta.index)),
        );
    }
    for field in &info.episode_fields {
        let value = episode.meta.fields.get(&field.key);
        features.insert(field.key.clone(), field_feature(field, value));
    }
    Ok(encode_example(&features))
}

/// A float image feature's values over an episode (one-channel float TIFFs of its size), as
/// one float tensor per step.
fn tiff_tensor(
    feature: &crate::episode::FeatureSpec,
    position: usize,
    episode: &Episode,
) -> Result<Feature, ExportError> {
    let mut flat = Vec::new();
    for step in &episode.steps {
        let values = match step.other.get(position) {
            Some(FeatureValue::Image(bytes)) => crate::media::tiff::decode_f32_tiff(bytes),
            _ => None,
        };
        let size = values
            .as_ref()
            .map(|(w, h, v)| (*w as usize, *h as usize, v.len()));
        match (values, feature.shape.as_slice()) {
            (Some((_, _, v)), [h, w, 1]) if size == Some((*w, *h, w * h)) => flat.extend(v),
            _ => {
                return Err(ExportError::InvalidOptions(format!(
                    "{}: episode {} holds images other than one-channel float TIFFs of its size, which RLDS cannot hold beside them (--without {} leaves the feature out)",
                    feature.name, episode.meta.index, feature.name
                )));
            }
        }
    }
    Ok(Feature::Float(flat))
}

/// Whether `bytes` are a TIFF file (a float image of another tool's LeRobot dataset).
pub(crate) fn is_tiff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*")
}

/// Whether the input has a per-episode value named `episode_metadata` itself, which leaves no
/// folder of that name for the `file_path` an episode of another tool's dataset gets.
pub(crate) fn metadata_taken(info: &DatasetInfo) -> bool {
    info.episode_fields
        .iter()
        .any(|f| f.key == "episode_metadata")
}

/// Another tool's per-episode value as RLDS stores it; where an episode has none, or one of
/// another kind or length, the declared kind's zero (an empty text), so every record holds
/// every key `features.json` declares.
fn field_feature(
    field: &crate::episode::EpisodeField,
    value: Option<&serde_json::Value>,
) -> Feature {
    use crate::episode::FieldDtype;
    use serde_json::Value;
    let items: Vec<&Value> = match value {
        Some(Value::Array(items)) => items.iter().collect(),
        Some(value) => vec![value],
        None => Vec::new(),
    };
    let fits = items.len() == field.len;
    match field.dtype {
        FieldDtype::Text => text(value.and_then(Value::as_str).unwrap_or_default()),
        FieldDtype::Float => Feature::Float(match fits {
            true => items
                .iter()
                .map(|v| v.as_f64().unwrap_or(0.0) as f32)
                .collect(),
            false => vec![0.0; field.len],
        }),
        FieldDtype::Int64 | FieldDtype::Bool => Feature::Int64(match fits {
            true => (items.iter())
                .map(|v| v.as_i64().or(v.as_bool().map(i64::from)).unwrap_or(0))
                .collect(),
            false => vec![0; field.len],
        }),
    }
}

/// Each step's images, encoded (steps in parallel); stored PNG and JPEG bytes copied.
fn step_images(
    layout: &StepLayout,
    episode: &Episode,
    png: PngLevel,
) -> Result<Vec<StepImages>, ExportError> {
    let (w, h) = (layout.width_px, layout.height_px);
    let [stored_rgb, stored_mask] = layout
        .png_features
        .clone()
        .map(|name| name.and_then(|n| episode.stored_png(&n)));
    let stored_jpeg = layout.png_features[0]
        .as_ref()
        .and_then(|n| episode.stored_frames(n, ImageEncoding::Jpeg));
    episode
        .steps
        .par_iter()
        .enumerate()
        .map(|(i, step)| {
            Ok(StepImages {
                rgb: match layout.jpeg_quality {
                    Some(quality) => {
                        stored_or(stored_jpeg, i, || encode_jpeg(w, h, &step.rgb, quality))?
                    }
                    None => stored_or(stored_rgb, i, || encode_png(w, h, 3, &step.rgb, png))?,
                },
                depth: if layout.depth {
                    let mm: Vec<u16> = step.depth_m.iter().map(|&d| depth_to_mm(d)).collect();
                    Some(encode_png16(w, h, &mm, png)?)
                } else {
                    None
                },
                mask: if layout.mask {
                    Some(stored_or(stored_mask, i, || {
                        encode_png(w, h, 1, &step.mask, png)
                    })?)
                } else {
                    None
                },
            })
        })
        .collect::<Result<_, ExportError>>()
}

/// The episode's provenance under `episode_metadata/`.
fn insert_metadata(features: &mut BTreeMap<String, Feature>, meta: &crate::episode::EpisodeMeta) {
    let metadata = |key: &str| format!("episode_metadata/{key}");
    features.insert(metadata("file_path"), text(&file_path(meta)));
    features.insert(
        metadata("episode_index"),
        Feature::Int64(vec![meta.index as i64]),
    );
    features.insert(metadata("task_id"), text(&meta.task_code));
    features.insert(
        metadata("level"),
        Feature::Int64(vec![i64::from(meta.level)]),
    );
    // uint64 travels as int64 (two's complement); TFDS casts it back.
    features.insert(metadata("seed"), Feature::Int64(vec![meta.seed as i64]));
    features.insert(
        metadata("attempts"),
        Feature::Int64(vec![i64::from(meta.attempts)]),
    );
    features.insert(
        metadata("success"),
        Feature::Int64(vec![i64::from(meta.success)]),
    );
}

/// The serialized Example of `episode` (its images encoded in parallel).
pub fn encode_episode(
    layout: &StepLayout,
    episode: &Episode,
    png: PngLevel,
) -> Result<Vec<u8>, ExportError> {
    let images = step_images(layout, episode, png)?;
    let steps = &episode.steps;
    let last = steps.len().saturating_sub(1);
    let meta = &episode.meta;
    let mut features = BTreeMap::new();
    let keys = &layout.keys;
    let mut images = images.into_iter().fold(
        (Vec::new(), Vec::new(), Vec::new()),
        |(mut rgb, mut depth, mut mask), step| {
            rgb.push(step.rgb);
            depth.extend(step.depth);
            mask.extend(step.mask);
            (rgb, depth, mask)
        },
    );
    features.insert(
        StepLayout::observation(&keys.image),
        Feature::Bytes(std::mem::take(&mut images.0)),
    );
    if layout.depth {
        features.insert(
            StepLayout::observation(&keys.depth),
            Feature::Bytes(std::mem::take(&mut images.1)),
        );
    }
    if layout.mask {
        features.insert(
            StepLayout::observation(&keys.mask),
            Feature::Bytes(std::mem::take(&mut images.2)),
        );
    }
    let floats = |pick: &dyn Fn(&Step) -> &[f32]| {
        Feature::Float(steps.iter().flat_map(|s| pick(s).iter().copied()).collect())
    };
    features.insert(StepLayout::observation(&keys.state), floats(&|s| &s.state));
    if layout.environment_state {
        features.insert(
            StepLayout::observation(&keys.environment_state),
            floats(&|s| &s.environment_state),
        );
    }
    features.insert("steps/action".into(), floats(&|s| &s.action));
    features.insert(
        "steps/language_instruction".into(),
        step_instructions(meta, steps.len()),
    );
    let flags = |on: &dyn Fn(usize) -> bool| {
        Feature::Int64((0..steps.len()).map(|i| i64::from(on(i))).collect())
    };
    features.insert("steps/is_first".into(), flags(&|i| i == 0));
    features.insert("steps/is_last".into(), flags(&|i| i == last));
    features.insert(
        "steps/is_terminal".into(),
        flags(&|i| i == last && meta.success),
    );
    features.insert(
        "steps/reward".into(),
        Feature::Float(
            (0..steps.len())
                .map(|i| f32::from(u8::from(i == last && meta.success)))
                .collect(),
        ),
    );
    features.insert(
        "steps/discount".into(),
        Feature::Float(vec![1.0; steps.len()]),
    );
    insert_metadata(&mut features, meta);
    Ok(encode_example(&features))
}

/// Takes the values of `key` out of an Example, checking their kind and count.
struct Fields {
    features: BTreeMap<String, Feature>,
}

impl Fields {
    fn take(&mut self, key: &str) -> Result<Feature, String> {
        self.features
            .remove(key)
            .ok_or_else(|| format!("has no {key}"))
    }

    fn floats(&mut self, key: &str, count: usize) -> Result<Vec<f32>, String> {
        match self.take(key)? {
            Feature::Float(values) if values.len() == count => Ok(values),
            Feature::Float(values) => Err(format!(
                "{key} has {} values where its steps need {count}",
                values.len()
            )),
            _ => Err(format!("{key} is not a float list")),
        }
    }

    fn ints(&mut self, key: &str, count: usize) -> Result<Vec<i64>, String> {
        match self.take(key)? {
            Feature::Int64(values) if values.len() == count => Ok(values),
            Feature::Int64(values) => Err(format!(
                "{key} has {} values where {count} were expected",
                values.len()
            )),
            _ => Err(format!("{key} is not an int64 list")),
        }
    }

    fn bytes(&mut self, key: &str, count: usize) -> Result<Vec<Vec<u8>>, String> {
        match self.take(key)? {
            Feature::Bytes(values) if values.len() == count => Ok(values),
            Feature::Bytes(values) => Err(format!(
                "{key} has {} values where {count} were expected",
                values.len()
            )),
            _ => Err(format!("{key} is not a bytes list")),
        }
    }

    fn text(&mut self, key: &str) -> Result<String, String> {
        let mut values = self.bytes(key, 1)?;
        String::from_utf8(values.remove(0)).map_err(|_| format!("{key} is not UTF-8"))
    }

    fn int(&mut self, key: &str) -> Result<i64, String> {
        Ok(self.ints(key, 1)?[0])
    }
}

fn copy(values: &[f32], into: &mut [f32]) {
    into.copy_from_slice(values);
}

/// One step's images from their stored bytes: the RGB (PNG or JPEG), and depth and mask when
/// the layout has them, each checked against the declared size.
fn decode_step_images(
    layout: &StepLayout,
    i: usize,
    rgb: &[u8],
    depth: Option<&Vec<u8>>,
    mask: Option<&Vec<u8>>,
) -> Result<Step, String> {
    let (w, h) = (layout.width_px, layout.height_px);
    let keys = &layout.keys;
    // The feature's full key is made only for an error: this runs once a step.
    let bad_image = |key: &String, i: usize, problem: String| {
        format!("{} step {i}: {problem}", StepLayout::observation(key))
    };
    let (image_key, depth_key, mask_key) = (&keys.image, &keys.depth, &keys.mask);
    let decoded = if is_jpeg(rgb) {
        decode_jpeg_sized(rgb, (w, h))
    } else {
        decode_png_sized(rgb, Some((w, h)))
    };
    let (rw, rh, channels, pixels) = decoded.map_err(|e| bad_image(image_key, i, e))?;
    if (rw as usize, rh as usize, channels) != (w, h, 3) {
        return Err(bad_image(
            image_key,
            i,
            format!("a {rw}x{rh} image with {channels} channels where {w}x{h} RGB was declared"),
        ));
    }
    let mut step = Step {
        rgb: pixels,
        ..Step::empty()
    };
    if layout.depth {
        let (dw, dh, mm) = decode_png16_sized(depth.map_or(&[][..], Vec::as_slice), Some((w, h)))
            .map_err(|e| bad_image(depth_key, i, e))?;
        if (dw as usize, dh as usize) != (w, h) {
            return Err(bad_image(depth_key, i, format!("a {dw}x{dh} depth image")));
        }
        step.depth_m = mm.iter().map(|&v| f32::from(v) / 1000.0).collect();
    }
    if layout.mask {
        let (mw, mh, channels, ids) =
            decode_png_sized(mask.map_or(&[][..], Vec::as_slice), Some((w, h)))
                .map_err(|e| bad_image(mask_key, i, e))?;
        if (mw as usize, mh as usize, channels) != (w, h, 1) {
            return Err(bad_image(
                mask_key,
                i,
                format!("a {mw}x{mh} mask with {channels} channels"),
            ));
        }
        step.mask = ids;
    }
    Ok(step)
}

/// The step flags hold only 0 and 1, and the first and last steps are marked.
fn check_flags(is_first: &[i64], is_last: &[i64], is_terminal: &[i64]) -> Result<(), String> {
    for (i, flags) in [is_first, is_last, is_terminal].into_iter().enumerate() {
        if flags.iter().any(|&v| v != 0 && v != 1) {
            let name = ["is_first", "is_last", "is_terminal"][i];
            return Err(format!("steps/{name} holds a value other than 0 and 1"));
        }
    }
    if is_first.first() != Some(&1) || is_last[is_last.len().saturating_sub(1)] != 1 {
        return Err("is_first or is_last is not set on the first or last step".into());
    }
    Ok(())
}

/// JPEG bytes are kept beside their pixels: copied when written as JPEG again, and the mark
/// that the pixels are lossy (verify and replay compare them within a tolerance).
fn stored_jpeg(layout: &StepLayout, rgb: &[Vec<u8>]) -> Vec<EncodedFeature> {
    match (&layout.png_features[0], rgb.first()) {
        (Some(feature), Some(first)) if is_jpeg(first) => vec![EncodedFeature {
            feature: feature.clone(),
            encoding: ImageEncoding::Jpeg,
            frames: rgb
                .iter()
                .map(|data| EncodedFrame {
                    data: data.clone(),
                    keyframe: true,
                })
                .collect(),
            pixel_stats: None,
            shown: None,
            file: None,
        }],
        _ => Vec::new(),
    }
}

/// Decodes one serialized Example into an episode; the error says what is wrong with it.
pub fn decode_episode(layout: &StepLayout, bytes: &[u8]) -> Result<Episode, String> {
    let mut fields = Fields {
        features: decode_example(bytes).map_err(|e| e.to_string())?,
    };
    let first = fields.take("steps/is_first")?;
    let Feature::Int64(is_first) = first else {
        return Err("steps/is_first is not an int64 list".into());
    };
    let count = is_first.len();
    if count == 0 {
        return Err("has no steps".into());
    }
    let keys = &layout.keys;
    let rgb = fields.bytes(&StepLayout::observation(&keys.image), count)?;
    let depth = if layout.depth {
        fields.bytes(&StepLayout::observation(&keys.depth), count)?
    } else {
        Vec::new()
    };
    let mask = if layout.mask {
        fields.bytes(&StepLayout::observation(&keys.mask), count)?
    } else {
        Vec::new()
    };
    let state = fields.floats(&StepLayout::observation(&keys.state), count * 7)?;
    let environment = if layout.environment_state {
        fields.floats(
            &StepLayout::observation(&keys.environment_state),
            count * MAX_OBJECTS * POSE_VALUES,
        )?
    } else {
        Vec::new()
    };
    let action = fields.floats("steps/action", count * 7)?;
    let instructions = fields.bytes("steps/language_instruction", count)?;
    let is_last = fields.ints("steps/is_last", count)?;
    let is_terminal = fields.ints("steps/is_terminal", count)?;
    fields.floats("steps/reward", count)?;
    fields.floats("steps/discount", count)?;
    check_flags(&is_first, &is_last, &is_terminal)?;
    let (instruction, task_changes) = step_instructions_read(&instructions)?;
    let steps = (0..count)
        .into_par_iter()
        .map(|i| {
            let mut step = decode_step_images(layout, i, &rgb[i], depth.get(i), mask.get(i))?;
            copy(&state[i * 7..(i + 1) * 7], &mut step.state);
            copy(&action[i * 7..(i + 1) * 7], &mut step.action);
            if layout.environment_state {
                let n = MAX_OBJECTS * POSE_VALUES;
                copy(
                    &environment[i * n..(i + 1) * n],
                    &mut step.environment_state,
                );
            }
            Ok(step)
        })
        .collect::<Result<Vec<Step>, String>>()?;
    let meta = EpisodeMeta {
        index: fields.int("episode_metadata/episode_index")? as u64,
        task_code: fields.text("episode_metadata/task_id")?,
        task_name: String::new(),
        level: fields.int("episode_metadata/level")? as u8,
        instruction,
        seed: fields.int("episode_metadata/seed")? as u64,
        attempts: fields.int("episode_metadata/attempts")? as u32,
        success: fields.int("episode_metadata/success")? == 1,
        task_changes,
        fields: serde_json::Map::new(),
    };
    let encoded = stored_jpeg(layout, &rgb);
    Ok(Episode {
        image_stats: Vec::new(),
        stored_rows: None,
        meta,
        steps,
        encoded,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn another_tools_episode_values_are_written_as_declared_or_as_zeros() {
        use crate::episode::{EpisodeField, FieldDtype};
        use serde_json::json;
        let field = |dtype, len| EpisodeField {
            key: "episode_metadata/x".into(),
            dtype,
            len,
        };
        // Each JSON value as its kind, and its kind declared from it.
        for (value, dtype, len, stored) in [
            (json!("ep 3"), FieldDtype::Text, 1, text("ep 3")),
            (json!(7), FieldDtype::Int64, 1, Feature::Int64(vec![7])),
            (
                json!([true, false]),
                FieldDtype::Bool,
                2,
                Feature::Int64(vec![1, 0]),
            ),
            (
                json!([0.5, 2]),
                FieldDtype::Float,
                2,
                Feature::Float(vec![0.5, 2.0]),
            ),
        ] {
            assert_eq!(FieldDtype::of_json(&value), Some((dtype, len)), "{value}");
            assert_eq!(
                field_feature(&field(dtype, len), Some(&value)),
                stored,
                "{value}"
            );
        }
        // None, or a value of another length: the kind's zeros, so every record has the key.
        assert_eq!(
            field_feature(&field(FieldDtype::Float, 2), None),
            Feature::Float(vec![0.0; 2])
        );
        let short = json!([1]);
        assert_eq!(
            field_feature(&field(FieldDtype::Int64, 3), Some(&short)),
            Feature::Int64(vec![0; 3])
        );
        assert_eq!(field_feature(&field(FieldDtype::Text, 1), None), text(""));
        assert_eq!(
            FieldDtype::of_json(&json!(["a", "b"])),
            None,
            "texts are one per key"
        );
        assert_eq!(FieldDtype::of_json(&json!(null)), None);
    }

    fn layout() -> StepLayout {
        StepLayout {
            keys: RldsKeys::default(),
            width_px: 4,
            height_px: 3,
            depth: true,
            mask: true,
            environment_state: true,
            png_features: [None, None],
            jpeg_quality: None,
        }
    }

    /// A seeded episode of `steps` random steps (depth on whole millimetres, so it survives).
    fn episode(seed: u64, steps: usize, success: bool) -> Episode {
        let mut rng = SplitMix64::new(seed);
        let mut byte = || (rng.next_u64() >> 56) as u8;
        let steps = (0..steps)
            .map(|i| Step {
                rgb: (0..36).map(|_| byte()).collect(),
                depth_m: (0..12)
                    .map(|k| ((i * 12 + k) % 300) as f32 / 1000.0)
                    .collect(),
                mask: (0..12).map(|_| byte() % 5).collect(),
                state: [i as f32, 0.5, -1.0, 0.1, 0.2, 0.3, 0.4],
                action: [0.001, -0.002, 0.0, 0.0, 0.01, -0.01, (i % 2) as f32],
                environment_state: [0.25; MAX_OBJECTS * POSE_VALUES],
                extras: Default::default(),
                other: Vec::new(),
            })
            .collect();
        Episode {
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
            meta: EpisodeMeta {
                index: 3,
                task_code: "T1-1".into(),
                task_name: String::new(),
                level: 1,
                instruction: "pick up the gauze".into(),
                seed: u64::MAX - seed,
                attempts: 2,
                success,
                task_changes: Vec::new(),
                fields: serde_json::Map::new(),
            },
            steps,
        }
    }

    #[test]
    fn seeded_episodes_round_trip_through_an_example() {
        for seed in 0..6u64 {
            let original = episode(seed, 1 + (seed as usize) * 3, seed % 2 == 0);
            let bytes = encode_episode(&layout(), &original, PngLevel::Fast).expect("encode");
            let decoded = decode_episode(&layout(), &bytes).expect("decode");
            assert_eq!(decoded, original, "seed {seed}");
        }
    }

    #[test]
    fn reward_and_terminal_mark_the_last_step_of_a_success_only() {
        let keys = |success| {
            let bytes =
                encode_episode(&layout(), &episode(1, 3, success), PngLevel::Fast).expect("encode");
            decode_example(&bytes).expect("decode")
        };
        let won = keys(true);
        assert_eq!(won["steps/reward"], Feature::Float(vec![0.0, 0.0, 1.0]));
        assert_eq!(won["steps/is_terminal"], Feature::Int64(vec![0, 0, 1]));
        assert_eq!(won["steps/is_first"], Feature::Int64(vec![1, 0, 0]));
        assert_eq!(
            won["episode_metadata/file_path"],
            text(&format!("T1-1/seed-{}", u64::MAX - 1))
        );
        let lost = keys(false);
        assert_eq!(lost["steps/reward"], Feature::Float(vec![0.0; 3]));
        assert_eq!(lost["steps/is_last"], Feature::Int64(vec![0, 0, 1]));
        assert_eq!(lost["steps/is_terminal"], Feature::Int64(vec![0; 3]));
    }

    #[test]
    fn depth_rounds_to_millimetres_and_saturates() {
        assert_eq!(depth_to_mm(0.1234), 123);
        assert_eq!(depth_to_mm(0.0), 0);
        assert_eq!(depth_to_mm(f32::NAN), 0);
        assert_eq!(depth_to_mm(100.0), u16::MAX);
    }

    #[test]
    fn a_wrong_step_count_or_image_names_the_key() {
        let bytes =
            encode_episode(&layout(), &episode(2, 2, true), PngLevel::Fast).expect("encode");
        let mut features = decode_example(&bytes).expect("decode");
        features.insert("steps/action".into(), Feature::Float(vec![0.0; 13]));
        let error = decode_episode(&layout(), &encode_example(&features)).unwrap_err();
        assert!(error.contains("steps/action has 13 values"), "{error}");
        let mut features = decode_example(&bytes).expect("decode");
        let rgba = encode_png(4, 3, 4, &[0; 48], PngLevel::Fast).expect("png");
        features.insert(
            "steps/observation/image".into(),
            Feature::Bytes(vec![rgba.clone(), rgba]),
        );
        let error = decode_episode(&layout(), &encode_example(&features)).unwrap_err();
        assert!(error.contains("4 channels"), "{error}");
    }
}
