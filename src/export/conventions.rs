//! What the dataset card says of surgvla's own data beyond its counts: how to load it (the
//! format's snippet), what its numbers mean (units, frames, the
//! state's and action's elements, the gripper's convention, how depth is stored, the mask's
//! ids), and the reference benchmark's full citation. Another tool's or a robot's data gets
//! none of this: surgvla does not know what its numbers mean.

use crate::episode::{FeatureKind, GripperEncoding};
use crate::export::info::DatasetInfo;
use std::fmt::Write as _;

/// The reference benchmark's paper, as its arXiv entry states it.
pub const BENCHMARK_BIBTEX: &str = "@misc{sun2026surgvlabench,
  title = {SurgVLA-Bench: Towards Evaluating Vision-Language-Action Models for Laparoscopic Surgical Robotics},
  author = {Sun, Jiashuo and He, Yue and Liu, Wenxuan and Mao, Tao and Wang, Jiazheng and Chen, Xiang and Liu, Min},
  year = {2026},
  eprint = {2606.29247},
  archivePrefix = {arXiv},
  primaryClass = {cs.AI},
  url = {https://arxiv.org/abs/2606.29247}
}";

/// The card's "Loading" section: the format's snippet, when it has one.
pub fn loading(snippet: Option<&str>) -> String {
    match snippet {
        Some(snippet) => format!("\n## Loading\n\n{}\n", snippet.trim_end()),
        None => String::new(),
    }
}

/// How the gripper element of the action reads, by the collection's encoding.
fn gripper(info: &DatasetInfo) -> &'static str {
    let pulse = (info.collection.as_ref())
        .and_then(|c| c.gripper_encoding())
        .is_some_and(|e| e == GripperEncoding::Pulse);
    if pulse {
        "a **pulse**: +1 on the step the jaws are commanded open, -1 on the step they are commanded closed, 0 otherwise (the jaws start open)"
    } else {
        "absolute and continuous: **1 while the jaws are commanded open, 0 while commanded closed**"
    }
}

/// The card's "Conventions" section for surgvla's own data (empty for anyone else's);
/// `depth`: how the format stores depth, a sentence.
pub fn conventions(info: &DatasetInfo, depth: &str) -> String {
    if !info.is_ours() {
        return String::new();
    }
    let mut card = String::from("\n## Conventions\n\n");
    card.push_str(
        "- **Units**: SI throughout (metres, radians, seconds); each element's name carries its unit (`tip_x_m`, `jaw_angle_rad`). Positions are in the simulator's world frame, z up; the table top is at z = 0.675 m.\n",
    );
    let named = |kind: FeatureKind| {
        (info.features.iter())
            .find(|f| f.kind == kind)
            .map(|f| (f.name.as_str(), f.names.join(", ")))
    };
    if let Some((name, names)) = named(FeatureKind::State) {
        let _ = writeln!(
            card,
            "- **`{name}`**: {names}. The tool tip's position, its orientation as Euler angles (`R = Rz(yaw) Ry(pitch) Rx(roll)`; pointing down reads roll = -90 deg, pitch = 0) and the jaws' opening angle."
        );
    }
    if let Some((name, _)) = named(FeatureKind::Action) {
        let _ = writeln!(
            card,
            "- **`{name}`**: dx, dy, dz (m) and droll, dpitch, dyaw (rad), the tip's change over one control step (1/{} s), in the world frame; then the gripper, {}.",
            info.fps,
            gripper(info)
        );
    }
    if let Some((name, _)) = named(FeatureKind::EnvironmentState) {
        let _ = writeln!(
            card,
            "- **`{name}`**: the movable objects' poses, x, y, z (m) and the quaternion qx, qy, qz, qw each, in scene order (the object the instruction names first), zero where a scene has fewer objects."
        );
    }
    if let Some((name, _)) = named(FeatureKind::Rgb) {
        let _ = writeln!(
            card,
            "- **`{name}`**: the endoscope's RGB image, 8 bits a channel (sRGB)."
        );
    }
    if let Some((name, _)) = named(FeatureKind::Depth) {
        let _ = writeln!(
            card,
            "- **`{name}`**: depth along the camera's optical axis, pixel-aligned with the RGB image; 0 where nothing lies within the far plane. {depth}"
        );
    }
    if let Some((name, _)) = named(FeatureKind::Mask) {
        let ids: Vec<String> = (info.mask_ids.iter())
            .map(|(id, object)| format!("{id} = {object}"))
            .collect();
        let _ = writeln!(
            card,
            "- **`{name}`**: each pixel's object id, 8 bits: {}.",
            ids.join(", ")
        );
    }
    card
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{FeatureSet, standard_features};
    use serde_json::json;

    fn info(gripper: &str) -> DatasetInfo {
        let surgvla = json!({
            "generator": "surgvla 0.1.0",
            "collection": {"seed": 0, "tasks": ["T1-1"], "gripper_encoding": gripper},
            "mask_ids": {"0": "background", "6": "gauze"},
        });
        let set = FeatureSet {
            mask: true,
            ..FeatureSet::default()
        };
        DatasetInfo::from_surgvla_json(&surgvla, 5, "dvrk_psm", standard_features(224, 224, set))
    }

    const DEPTH: &str = "Stored as float32 TIFF images in metres.";

    #[test]
    fn our_data_is_said_to_mean_what_it_holds() {
        let said = conventions(&info("continuous"), DEPTH);
        for part in [
            "## Conventions",
            "tip_x_m, tip_y_m, tip_z_m, tip_roll_rad, tip_pitch_rad, tip_yaw_rad, jaw_angle_rad",
            "one control step (1/5 s)",
            "**1 while the jaws are commanded open, 0 while commanded closed**",
            DEPTH,
            "each pixel's object id, 8 bits: 0 = background, 6 = gauze.",
        ] {
            assert!(said.contains(part), "{part}\n{said}");
        }
        let pulse = conventions(&info("pulse"), DEPTH);
        assert!(pulse.contains("a **pulse**: +1 on the step"), "{pulse}");
        assert!(!pulse.contains("1 while the jaws"), "{pulse}");
        let mut foreign = info("continuous");
        foreign.generator = String::new();
        foreign.collection = None;
        assert!(conventions(&foreign, DEPTH).is_empty());
        assert_eq!(loading(None), "");
        assert_eq!(loading(Some("With x:\n")), "\n## Loading\n\nWith x:\n");
    }
}
