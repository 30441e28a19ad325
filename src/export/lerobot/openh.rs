//! `validate --profile open-h`: Open-H-Embodiment's contribution guide as checks, on top of the
//! LeRobot checks (which decode every video frame, where Open-H's own validator opens the first
//! three files). The guide asks for LeRobot v2.1 in video mode (lerobot 0.3.3), `action` and
//! `observation.state`, cameras as `observation.images.*`, healthcare extras as
//! `observation.meta.*` and `instruction.text`, `splits` with train/val/test (and `recovery` /
//! `failure` where there are such episodes), at least 20 Hz and 480p, the robot type, and a
//! `meta/README.md` from its template that documents how the streams were synchronised.
//!
//! Severities follow Open-H's validator (`scripts/validation/validate_formatting.py`): what it
//! calls an error is an error here, what it warns of a warning. Where this profile is stricter
//! (the README's synchronisation section, a camera not named `observation.images.*`), it says so
//! in docs/validate.md.

use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::findings::{At, Findings};
use crate::export::lerobot::meta::{FeatureJson, InfoJson};
use std::path::Path;

/// The guide's floor for the frame rate (Hz) and image size (pixels, each side).
pub const MIN_FPS: f64 = 20.0;
pub const MIN_SIDE_PX: usize = 480;

/// Checks the dataset at `root` (found as `layout`) against Open-H's guide.
pub fn check(root: &Path, layout: &str, findings: &Findings) {
    let error = |file: &str, message: String| {
        findings.error(At::file(file), Check::Profile, format!("Open-H: {message}"));
    };
    let warning = |file: &str, message: String| {
        findings.warning(At::file(file), Check::Profile, format!("Open-H: {message}"));
    };
    if layout != "lerobot-v2.1" {
        error(
            ".",
            format!(
                "takes LeRobot v2.1 (lerobot 0.3.3); this is {layout}: convert it with `surgvla convert --to lerobot --lerobot-version 2.1 --video av1`"
            ),
        );
        return;
    }
    for file in [
        "info.json",
        "episodes.jsonl",
        "tasks.jsonl",
        "episodes_stats.jsonl",
    ] {
        if !root.join("meta").join(file).is_file() {
            error(&format!("meta/{file}"), "is required and missing".into());
        }
    }
    readme(root, &error);
    let Ok(value) = read_json(&root.join("meta/info.json")) else {
        return; // the LeRobot checks name it
    };
    let info: InfoJson = serde_json::from_value(value).unwrap_or_default();
    let features = info.feature_list();
    for required in ["action", "observation.state"] {
        if !features.iter().any(|(name, _)| name == required) {
            error(
                "meta/info.json",
                format!("the feature {required:?} is required"),
            );
        }
    }
    cameras(&features, root, &error, &warning);
    if !features
        .iter()
        .any(|(name, _)| name.starts_with("observation.meta.") || name == "instruction.text")
    {
        warning(
            "meta/info.json",
            "no healthcare metadata (observation.meta.* such as observation.meta.tool, or instruction.text)".into(),
        );
    }
    match info.fps_hz() {
        Some(fps) if fps < MIN_FPS => warning(
            "meta/info.json",
            format!("fps {fps} is below the guide's {MIN_FPS} Hz"),
        ),
        _ => {}
    }
    if info.robot_type.as_deref().is_none_or(str::is_empty) {
        warning("meta/info.json", "robot_type is not stated".into());
    }
    match &info.splits {
        None => warning("meta/info.json", "no splits".into()),
        Some(splits) => {
            for split in ["train", "val", "test"] {
                if !splits.contains_key(split) {
                    warning("meta/info.json", format!("no {split:?} split"));
                }
            }
            if !splits.contains_key("recovery") {
                warning(
                    "meta/info.json",
                    "no \"recovery\" split (the guide asks for recovery examples; and \"failure\" for failures)".into(),
                );
            }
        }
    }
}

/// `meta/README.md` is required (an error, as Open-H's validator has it) and documents the
/// synchronisation (a heading that names it: this profile's requirement, from the guide).
fn readme(root: &Path, error: &dyn Fn(&str, String)) {
    let path = root.join("meta/README.md");
    let text = crate::export::bounded::read_metadata(&path)
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned());
    let Ok(text) = text else {
        error(
            "meta/README.md",
            "is required (the guide's dataset template) and missing".into(),
        );
        return;
    };
    let documents_sync = text.lines().any(|line| {
        let line = line.trim_start().to_lowercase();
        line.starts_with('#') && line.contains("synchron")
    });
    if !documents_sync {
        error(
            "meta/README.md",
            "has no section on synchronisation (a heading naming it: how the streams were aligned)"
                .into(),
        );
    }
}

/// Cameras: video features (image features are stored as PNG, not as the guide's video),
/// named `observation.images.*`, at least 480 pixels each side.
fn cameras(
    features: &[(String, FeatureJson)],
    root: &Path,
    error: &dyn Fn(&str, String),
    warning: &dyn Fn(&str, String),
) {
    let cameras: Vec<&(String, FeatureJson)> = (features.iter())
        .filter(|(_, f)| matches!(f.dtype.as_deref(), Some("video" | "image")))
        .collect();
    if cameras.is_empty() {
        warning("meta/info.json", "no camera (observation.images.*)".into());
    }
    if !cameras.is_empty() && !root.join("videos").is_dir() {
        error(
            "videos",
            "is required: the guide stores cameras as video".into(),
        );
    }
    for (name, feature) in cameras {
        if !name.starts_with("observation.images.") {
            error(
                "meta/info.json",
                format!("the camera {name:?} is not named observation.images.*"),
            );
        }
        if feature.dtype.as_deref() == Some("image") {
            warning(
                "meta/info.json",
                format!("{name} is stored as images; the guide asks for video"),
            );
        }
        if let Some([height, width, ..]) = feature.shape.as_deref()
            && (*height < MIN_SIDE_PX || *width < MIN_SIDE_PX)
        {
            warning(
                "meta/info.json",
                format!("{name} is {width}x{height}, below the guide's {MIN_SIDE_PX}p"),
            );
        }
    }
}
