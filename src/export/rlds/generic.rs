//! Checking RLDS records of any dataset against its own `features.json`, not our step layout:
//! an Open X-Embodiment dataset written by tensorflow_datasets has other keys and shapes. The
//! feature tree gives each leaf's flattened key (`steps/observation/image`), kind, shape and
//! dtype; every record must hold every leaf and nothing else, steps-level leaves with the same
//! step count, images that decode with the declared size and channels (RGB, not RGBA), finite
//! floats, `is_first` / `is_last` / `is_terminal` as 0/1 on the right steps, and a non-empty
//! language instruction.

use crate::export::check::Check;
use crate::export::rlds::example::Feature;
use crate::media::image::{decode_png, decode_png16, png_size};
use serde_json::Value;
use std::collections::BTreeMap;

/// A leaf of the feature tree.
#[derive(Clone, Debug, PartialEq)]
pub enum Leaf {
    /// Tensor or Scalar: values per step (or per episode outside `steps/`).
    Tensor {
        dtype: String,
        elements: usize,
        /// The declared dimensions (empty for a scalar).
        dims: Vec<usize>,
    },
    /// An encoded image with (height, width, channels); dimensions may be unknown (None).
    Image {
        shape: [Option<usize>; 3],
        dtype: String,
        /// The declared `encodingFormat` ("png", "jpeg"), when stated.
        format: Option<String>,
    },
    Text,
}

/// Every leaf of `features.json` by flattened key ("steps/observation/image"); `Err` names a
/// node surgvla does not understand.
pub fn leaves(features: &Value) -> Result<BTreeMap<String, Leaf>, String> {
    let mut out = BTreeMap::new();
    walk(features, "", &mut out)?;
    Ok(out)
}

fn dimension(value: &Value) -> Option<usize> {
    value
        .as_str()
        .and_then(|s| s.parse::<i64>().ok())
        .or_else(|| value.as_i64())
        .filter(|v| *v >= 0)
        .map(|v| v as usize)
}

fn walk(node: &Value, prefix: &str, out: &mut BTreeMap<String, Leaf>) -> Result<(), String> {
    let class = node["pythonClassName"].as_str().unwrap_or_default();
    let join = |key: &str| {
        if prefix.is_empty() {
            key.to_string()
        } else {
            format!("{prefix}/{key}")
        }
    };
    if let Some(children) = node["featuresDict"]["features"].as_object() {
        for (key, child) in children {
            walk(child, &join(key), out)?;
        }
        return Ok(());
    }
    if let Some(feature) = node.get("sequence").map(|s| &s["feature"]) {
        return walk(feature, prefix, out);
    }
    if class.ends_with("Image") || node.get("image").is_some() {
        let dims = node["image"]["shape"]["dimensions"].as_array();
        let dim = |i: usize| dims.and_then(|d| d.get(i)).and_then(dimension);
        out.insert(
            prefix.to_string(),
            Leaf::Image {
                shape: [dim(0), dim(1), dim(2)],
                dtype: node["image"]["dtype"].as_str().unwrap_or("uint8").into(),
                format: node["image"]["encodingFormat"].as_str().map(String::from),
            },
        );
        return Ok(());
    }
    if class.ends_with("Text") || node.get("text").is_some() {
        out.insert(prefix.to_string(), Leaf::Text);
        return Ok(());
    }
    if let Some(tensor) = node.get("tensor") {
        let dims: Vec<usize> = (tensor["shape"]["dimensions"].as_array())
            .map(|d| d.iter().map(|v| dimension(v).unwrap_or(1)).collect())
            .unwrap_or_default();
        out.insert(
            prefix.to_string(),
            Leaf::Tensor {
                dtype: tensor["dtype"].as_str().unwrap_or_default().into(),
                elements: dims.iter().product(),
                dims,
            },
        );
        return Ok(());
    }
    Err(format!("{prefix}: a {class} node surgvla does not read"))
}

/// What is wrong with one decoded record, as (step, check, message); empty when nothing.
pub fn check_record(
    leaves: &BTreeMap<String, Leaf>,
    record: &BTreeMap<String, Feature>,
    decode_images: bool,
) -> Problems {
    let mut problems = Vec::new();
    for key in record.keys() {
        if !leaves.contains_key(key) {
            problems.push((
                None,
                Check::Features,
                format!("{key} is in the record but not in features.json"),
            ));
        }
    }
    let steps = step_count(leaves, record);
    if steps == 0 {
        problems.push((None, Check::Steps, "the episode has zero steps".into()));
        return problems;
    }
    for (key, leaf) in leaves {
        check_leaf(key, leaf, record, steps, decode_images, &mut problems);
    }
    check_flags(record, steps, &mut problems);
    problems
}

/// A record's problems: (step, check, what).
type Problems = Vec<(Option<u64>, Check, String)>;

/// The episode's steps: the length of `steps/is_first`, or of the first per-step feature.
fn step_count(leaves: &BTreeMap<String, Leaf>, record: &BTreeMap<String, Feature>) -> usize {
    let first = record.get("steps/is_first").or_else(|| {
        leaves
            .keys()
            .find(|k| k.starts_with("steps/"))
            .and_then(|k| record.get(k))
    });
    match first {
        Some(Feature::Int64(v)) => v.len(),
        Some(Feature::Float(v)) => v.len(),
        Some(Feature::Bytes(v)) => v.len(),
        None => 0,
    }
}

/// One declared feature: present, holding a value per step (times its elements), finite,
/// instructions not blank, images decoding to their declared shape.
fn check_leaf(
    key: &str,
    leaf: &Leaf,
    record: &BTreeMap<String, Feature>,
    steps: usize,
    decode_images: bool,
    problems: &mut Problems,
) {
    let per_step = key.starts_with("steps/");
    let count = if per_step { steps } else { 1 };
    let Some(value) = record.get(key) else {
        problems.push((
            None,
            Check::Features,
            format!("{key} is declared in features.json but missing"),
        ));
        return;
    };
    let (len, kind) = match value {
        Feature::Int64(v) => (v.len(), "int64"),
        Feature::Float(v) => (v.len(), "float"),
        Feature::Bytes(v) => (v.len(), "bytes"),
    };
    let expected = match leaf {
        Leaf::Tensor { elements, .. } => count * elements,
        _ => count,
    };
    if len != expected {
        problems.push((
            None,
            Check::StepCounts,
            format!("{key} holds {len} {kind} values where {count} steps need {expected}"),
        ));
        return;
    }
    match (leaf, value) {
        (_, Feature::Float(values)) => {
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                let step = per_step.then_some((i / (len / count).max(1)) as u64);
                problems.push((step, Check::Finite, format!("{key} holds {}", values[i])));
            }
        }
        (Leaf::Text, Feature::Bytes(texts)) if key.ends_with("language_instruction") => {
            if let Some(i) = texts
                .iter()
                .position(|t| t.iter().all(u8::is_ascii_whitespace))
            {
                problems.push((
                    Some(i as u64),
                    Check::Instruction,
                    format!("{key} is empty"),
                ));
            }
        }
        (
            Leaf::Image {
                shape,
                dtype,
                format,
            },
            Feature::Bytes(images),
        ) if decode_images => {
            let first_bad = images.iter().enumerate().find_map(|(i, bytes)| {
                let problem = (format_problem(bytes, format.as_deref()))
                    .or_else(|| image_problem(bytes, *shape, dtype))?;
                Some((i, problem))
            });
            if let Some((i, problem)) = first_bad {
                problems.push((
                    per_step.then_some(i as u64),
                    Check::Image,
                    format!("{key} {problem}"),
                ));
            }
        }
        _ => {}
    }
}

/// `is_first` true on the first step only, `is_last` on the last only, `is_terminal` (optional)
/// nowhere but the last; all 0/1.
fn check_flags(record: &BTreeMap<String, Feature>, steps: usize, problems: &mut Problems) {
    for (name, first_last) in [
        ("is_first", true),
        ("is_last", false),
        ("is_terminal", false),
    ] {
        let key = format!("steps/{name}");
        let Some(Feature::Int64(flags)) = record.get(&key) else {
            if name != "is_terminal" {
                problems.push((
                    None,
                    Check::Flags,
                    format!("{key} is missing or not a 0/1 list"),
                ));
            }
            continue;
        };
        if let Some(i) = flags.iter().position(|v| *v != 0 && *v != 1) {
            problems.push((
                Some(i as u64),
                Check::Flags,
                format!("{key} is {}, not 0 or 1", flags[i]),
            ));
            continue;
        }
        let at = if first_last { 0 } else { steps - 1 };
        let wrong = match name {
            "is_first" | "is_last" => flags
                .iter()
                .enumerate()
                .position(|(i, v)| (*v == 1) != (i == at)),
            _ => flags
                .iter()
                .enumerate()
                .position(|(i, v)| *v == 1 && i != at),
        };
        if let Some(i) = wrong {
            problems.push((
                Some(i as u64),
                Check::Flags,
                format!("{key} is {} on step {i} of {steps}", flags[i]),
            ));
        }
    }
}

/// What is wrong with one encoded image, if anything.
/// Bytes of another encoding than the `declared` one (JPEG under `png`, say): a reader that
/// decodes by the declared format (TFDS) fails on them, or worse.
fn format_problem(bytes: &[u8], declared: Option<&str>) -> Option<String> {
    let found = if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
        "jpeg"
    } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        "png"
    } else {
        return None;
    };
    let declared = declared?.to_ascii_lowercase();
    let same = declared == found || (found == "jpeg" && declared == "jpg");
    (!same).then(|| {
        format!("holds {found} bytes where features.json declares encodingFormat {declared:?}")
    })
}

fn image_problem(bytes: &[u8], shape: [Option<usize>; 3], dtype: &str) -> Option<String> {
    if bytes.starts_with(&[0xff, 0xd8]) {
        return None; // JPEG: not decoded here.
    }
    // A size other than the declared one is known from the header: nothing is decoded.
    let declared = shape[1].zip(shape[0]);
    if let (Some(declared), Some((w, h))) = (declared, png_size(bytes))
        && declared != (w, h)
    {
        return Some(format!(
            "is {w}x{h}, declared {:?}x{:?}",
            shape[1], shape[0]
        ));
    }
    let (w, h, c) = if dtype == "uint16" {
        match decode_png16(bytes) {
            Ok((w, h, _)) => (w as usize, h as usize, 1),
            Err(e) => return Some(format!("does not decode: {e}")),
        }
    } else {
        match decode_png(bytes) {
            Ok((w, h, c, _)) => (w as usize, h as usize, c),
            Err(e) => return Some(format!("does not decode: {e}")),
        }
    };
    if shape[0].is_some_and(|v| v != h) || shape[1].is_some_and(|v| v != w) {
        return Some(format!(
            "is {w}x{h}, declared {:?}x{:?}",
            shape[1], shape[0]
        ));
    }
    if shape[2].is_some_and(|v| v != c) {
        let rgba = if c == 4 {
            " (RGBA: RLDS readers expect RGB)"
        } else {
            ""
        };
        return Some(format!("has {c} channels, declared {:?}{rgba}", shape[2]));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_of_another_encoding_than_declared_are_named() {
        let jpeg = [0xff, 0xd8, 0xff, 0xe0, 0, 0];
        let png = *b"\x89PNG\r\n\x1a\n\0\0";
        let problem = format_problem(&jpeg, Some("png")).expect("JPEG under png");
        assert!(problem.contains("jpeg bytes"), "{problem}");
        assert!(format_problem(&png, Some("jpeg")).is_some());
        assert_eq!(format_problem(&jpeg, Some("jpeg")), None);
        assert_eq!(format_problem(&jpeg, Some("JPG")), None);
        assert_eq!(format_problem(&png, Some("png")), None);
        assert_eq!(format_problem(&png, None), None, "nothing declared");
        assert_eq!(
            format_problem(b"GIF89a", Some("png")),
            None,
            "left to the decoder"
        );
    }
}
