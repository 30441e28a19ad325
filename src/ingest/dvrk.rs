//! The dVRK preset: which topics of a da Vinci Research Kit recording make which features,
//! with the CRTK names of dVRK 2.x. Per arm (`PSM1`, or a full namespace such as `/dvrk/PSM1`
//! for dVRK 1.x), `measured_cp` + `jaw/measured_js` are the state [x, y, z, qx, qy, qz, qw, jaw]
//! (metres, radians) and `setpoint_cp` + `jaw/setpoint_js` the action (the same 8); arms are
//! concatenated in the order given. Each camera (`NAME=TOPIC`) is an RGB image; a
//! `std_msgs/String` on `/instruction`, when the recording has one, is the task.
//!
//! Measured streams and cameras are *sampled* (too old a message and the frame is not
//! written); setpoints and the instruction are *events* (their last value holds).

use crate::ingest::decode::RosValue;
use crate::ingest::extract::{
    DepthImage, RgbImage, joint_positions, pose_frames, pose7, raw_depth, rgb,
};

/// A feature's own facts (its `info`).
pub type FeatureInfo = serde_json::Map<String, serde_json::Value>;
use crate::ingest::map::MappedFeature;
use crate::ingest::stamps::TopicSpec;
use crate::ingest::sync::StreamKind;

/// The topic of the task's text.
pub const INSTRUCTION_TOPIC: &str = "/instruction";

/// A dVRK recording's mapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DvrkPreset {
    /// Arm namespaces, e.g. `/PSM1`.
    pub arms: Vec<String>,
    /// (feature name, topic) per camera.
    pub cameras: Vec<(String, String)>,
    /// (feature name, topic) per depth camera (16UC1 or 32FC1), after the cameras.
    pub depths: Vec<(String, String)>,
    /// Features of topics the preset does not cover (`--map`), after the cameras' topics.
    pub mapped: Vec<MappedFeature>,
}

/// One frame's features.
#[derive(Clone, Debug, PartialEq)]
pub struct DvrkFrame {
    /// 8 per arm.
    pub state: Vec<f32>,
    /// 8 per arm.
    pub action: Vec<f32>,
    /// One per camera, in order.
    pub images: Vec<RgbImage>,
    /// One per depth camera, in order.
    pub depths: Vec<DepthImage>,
    /// Each mapped feature's values, in order.
    pub mapped: Vec<Vec<f32>>,
    /// The instruction topic's text, when it has one.
    pub instruction: Option<String>,
}

/// The per-arm topics, in slot order, with their kinds.
const ARM_TOPICS: [(&str, StreamKind); 4] = [
    ("measured_cp", StreamKind::Sampled),
    ("jaw/measured_js", StreamKind::Sampled),
    ("setpoint_cp", StreamKind::Event),
    ("jaw/setpoint_js", StreamKind::Event),
];

/// The names of one arm's 8 values.
const ARM_VALUES: [&str; 8] = ["x", "y", "z", "qx", "qy", "qz", "qw", "jaw"];

impl DvrkPreset {
    /// `arms` as given on the command line (`PSM1`, or a namespace `/dvrk/PSM1`) and cameras.
    pub fn new(arms: &[String], cameras: &[(String, String)]) -> DvrkPreset {
        let arms = arms
            .iter()
            .map(|arm| {
                let arm = arm.trim_end_matches('/');
                if arm.starts_with('/') {
                    arm.to_string()
                } else {
                    format!("/{arm}")
                }
            })
            .collect();
        DvrkPreset {
            arms,
            cameras: cameras.to_vec(),
            depths: Vec::new(),
            mapped: Vec::new(),
        }
    }

    /// The preset with depth cameras (`--depth NAME=TOPIC`).
    pub fn with_depths(mut self, depths: &[(String, String)]) -> DvrkPreset {
        self.depths = depths.to_vec();
        self
    }

    /// Every image feature's (name, topic): the cameras, then the depth cameras.
    pub fn image_topics(&self) -> impl Iterator<Item = &(String, String)> {
        self.cameras.iter().chain(&self.depths)
    }

    /// The preset with features of more topics (`--map`).
    pub fn with_mapped(mut self, mapped: Vec<MappedFeature>) -> DvrkPreset {
        self.mapped = mapped;
        self
    }

    /// Every topic the preset reads, in slot order: each arm's four, the cameras, then the
    /// instruction (optional: left out when the recording has none).
    pub fn topics(&self) -> Vec<TopicSpec> {
        let spec = |topic: String, kind| TopicSpec {
            topic,
            kind,
            offset_ns: 0,
        };
        let arms = self.arms.iter().flat_map(|arm| {
            ARM_TOPICS
                .iter()
                .map(move |(name, kind)| spec(format!("{arm}/{name}"), *kind))
        });
        let cameras =
            (self.image_topics()).map(|(_, topic)| spec(topic.clone(), StreamKind::Sampled));
        let mapped = (self.mapped.iter()).map(|m| spec(m.topic.clone(), m.stream_kind()));
        arms.chain(cameras)
            .chain(mapped)
            .chain([spec(INSTRUCTION_TOPIC.into(), StreamKind::Event)])
            .collect()
    }

    /// How many topics [`DvrkPreset::topics`] lists, without building them.
    pub fn topic_count(&self) -> usize {
        self.arms.len() * ARM_TOPICS.len()
            + self.cameras.len()
            + self.depths.len()
            + self.mapped.len()
            + 1
    }

    /// The names of the state's (and the action's) values: `PSM1.x`, ..., `PSM1.jaw`, per arm.
    pub fn value_names(&self) -> Vec<String> {
        self.arms
            .iter()
            .flat_map(|arm| {
                let arm = arm.rsplit('/').next().unwrap_or(arm).to_string();
                ARM_VALUES.iter().map(move |v| format!("{arm}.{v}"))
            })
            .collect()
    }

    /// Where each camera's (then each depth camera's) `sensor_msgs/CameraInfo` may be, beside its image topic:
    /// `.../camera_info` next to it, and for an image transport's `.../compressed` topic next
    /// to the image topic it compresses; per camera, in order of preference.
    pub fn camera_info_topics(&self) -> Vec<Vec<String>> {
        let sibling = |topic: &str| {
            topic
                .rsplit_once('/')
                .map(|(parent, _)| format!("{parent}/camera_info"))
        };
        (self.image_topics())
            .map(|(_, topic)| {
                let mut candidates: Vec<String> = sibling(topic).into_iter().collect();
                if let Some(base) = topic.strip_suffix("/compressed") {
                    candidates.extend(sibling(base));
                }
                candidates.retain(|c| c != topic && c != "/camera_info");
                candidates
            })
            .collect()
    }

    /// The frames the state's and the action's poses are in, from a frame's messages (see
    /// [`crate::ingest::extract::pose_frames`]): the `info` of `observation.state` and of
    /// `action`.
    pub fn pose_info(&self, values: &[std::sync::Arc<RosValue>]) -> (FeatureInfo, FeatureInfo) {
        let (mut state, mut action) = (FeatureInfo::new(), FeatureInfo::new());
        for (a, arm) in self.arms.iter().enumerate() {
            let name = arm.rsplit('/').next().unwrap_or(arm);
            for (slot, info) in [(0, &mut state), (2, &mut action)] {
                if let Some(message) = values.get(a * 4 + slot) {
                    info.extend(pose_frames(name, message));
                }
            }
        }
        (state, action)
    }

    /// A frame's features from its messages, one per topic of [`DvrkPreset::topics`] (the
    /// instruction's last, when present).
    pub fn frame(&self, values: &[std::sync::Arc<RosValue>]) -> Result<DvrkFrame, String> {
        let (mut state, mut action) = (Vec::new(), Vec::new());
        for (a, arm) in self.arms.iter().enumerate() {
            let at = |k: usize| {
                values
                    .get(a * 4 + k)
                    .ok_or_else(|| format!("{arm}: no {} message", ARM_TOPICS[k].0))
            };
            let arm_values = |pose: &RosValue, jaw: &RosValue, what: &str| {
                let pose = pose7(pose).map_err(|e| format!("{arm}/{what}_cp {e}"))?;
                let jaw = joint_positions(jaw).map_err(|e| format!("{arm}/jaw/{what}_js {e}"))?;
                let jaw = *jaw
                    .first()
                    .ok_or_else(|| format!("{arm}/jaw/{what}_js holds no position"))?;
                Ok::<_, String>(pose.into_iter().chain([jaw]).map(|v| v as f32))
            };
            state.extend(arm_values(at(0)?, at(1)?, "measured")?);
            action.extend(arm_values(at(2)?, at(3)?, "setpoint")?);
        }
        let first_camera = self.arms.len() * 4;
        let mut images = Vec::with_capacity(self.cameras.len());
        for (c, (name, topic)) in self.cameras.iter().enumerate() {
            let message = values
                .get(first_camera + c)
                .ok_or_else(|| format!("camera {name}: no message on {topic}"))?;
            images.push(rgb(message).map_err(|e| format!("camera {name} ({topic}): {e}"))?);
        }
        let first_depth = first_camera + self.cameras.len();
        let mut depths = Vec::with_capacity(self.depths.len());
        for (d, (name, topic)) in self.depths.iter().enumerate() {
            let message = values
                .get(first_depth + d)
                .ok_or_else(|| format!("depth camera {name}: no message on {topic}"))?;
            depths.push(
                raw_depth(message).map_err(|e| format!("depth camera {name} ({topic}): {e}"))?,
            );
        }
        let first_mapped = first_depth + self.depths.len();
        let mut mapped = Vec::with_capacity(self.mapped.len());
        for (m, feature) in self.mapped.iter().enumerate() {
            let message = (values.get(first_mapped + m))
                .ok_or_else(|| format!("{}: no message on {}", feature.name, feature.topic))?;
            let got = feature.extract(message);
            mapped.push(got.map_err(|e| format!("{} ({}) {e}", feature.name, feature.topic))?);
        }
        let instruction = (values.len() == self.topic_count())
            .then(|| values.last())
            .flatten()
            .and_then(|v| v.field("data"))
            .and_then(RosValue::as_str)
            .map(String::from);
        Ok(DvrkFrame {
            state,
            action,
            images,
            depths,
            mapped,
            instruction,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    use crate::ingest::fixtures::message;

    fn pose(x: f64) -> RosValue {
        let xyz = message(vec![
            ("x", RosValue::Float(x)),
            ("y", RosValue::Float(2.0)),
            ("z", RosValue::Float(3.0)),
        ]);
        let q = message(vec![
            ("x", RosValue::Float(0.0)),
            ("y", RosValue::Float(0.0)),
            ("z", RosValue::Float(0.0)),
            ("w", RosValue::Float(1.0)),
        ]);
        message(vec![(
            "pose",
            message(vec![("position", xyz), ("orientation", q)]),
        )])
    }

    fn jaw(angle: f64) -> RosValue {
        message(vec![(
            "position",
            RosValue::Array(vec![RosValue::Float(angle)]),
        )])
    }

    #[test]
    fn topics_names_and_a_frame_of_one_arm_and_a_camera() {
        let preset = DvrkPreset::new(
            &["PSM1".into()],
            &[("left".into(), "/cam/left/image_raw".into())],
        );
        assert_eq!(preset.topic_count(), preset.topics().len());
        let topics: Vec<String> = preset.topics().into_iter().map(|t| t.topic).collect();
        assert_eq!(
            topics,
            [
                "/PSM1/measured_cp",
                "/PSM1/jaw/measured_js",
                "/PSM1/setpoint_cp",
                "/PSM1/jaw/setpoint_js",
                "/cam/left/image_raw",
                "/instruction"
            ]
        );
        assert_eq!(preset.value_names()[7], "PSM1.jaw");
        let image = message(vec![
            ("height", RosValue::UInt(1)),
            ("width", RosValue::UInt(1)),
            ("encoding", RosValue::String("bgr8".into())),
            ("step", RosValue::UInt(3)),
            ("data", RosValue::Bytes(vec![1, 2, 3])),
        ]);
        let text = message(vec![("data", RosValue::String("pick up the gauze".into()))]);
        let values: Vec<Arc<RosValue>> = [pose(1.0), jaw(0.5), pose(1.5), jaw(0.25), image, text]
            .into_iter()
            .map(Arc::new)
            .collect();
        let frame = preset.frame(&values).expect("frame");
        assert_eq!(frame.state, [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.5]);
        assert_eq!(frame.action, [1.5, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.25]);
        assert_eq!(frame.images[0].rgb, [3, 2, 1]);
        assert_eq!(frame.instruction.as_deref(), Some("pick up the gauze"));
        // The fixture's poses name no frame.
        assert!(preset.pose_info(&values).0.is_empty());
        assert_eq!(preset.camera_info_topics(), [["/cam/left/camera_info"]]);
        let compressed =
            DvrkPreset::new(&[], &[("l".into(), "/cam/l/image_raw/compressed".into())]);
        assert_eq!(
            compressed.camera_info_topics(),
            [["/cam/l/image_raw/camera_info", "/cam/l/camera_info"]]
        );
        // Without the instruction topic.
        let frame = preset.frame(&values[..5]).expect("frame");
        assert_eq!(frame.instruction, None);
        // A jaw without a position is named.
        let mut broken = values.clone();
        broken[1] = Arc::new(message(vec![("position", RosValue::Array(Vec::new()))]));
        let error = preset.frame(&broken).expect_err("no jaw");
        assert!(error.contains("/PSM1/jaw/measured_js"), "{error}");
    }

    #[test]
    fn dvrk_1_namespaces_and_two_arms() {
        let preset = DvrkPreset::new(&["/dvrk/PSM1/".into(), "PSM2".into()], &[]);
        assert_eq!(preset.arms, ["/dvrk/PSM1", "/PSM2"]);
        assert_eq!(preset.topics()[4].topic, "/PSM2/measured_cp");
        let names = preset.value_names();
        assert_eq!((names[0].as_str(), names[8].as_str()), ("PSM1.x", "PSM2.x"));
    }
}
