//! Series to plant defects in, for the checks' tests.

use super::judge::lint;
use super::series::{EpisodeSeries, LintDataset, LintFeature, Series};
use crate::episode::GripperEncoding;
use crate::export::findings::Findings;
use std::collections::BTreeMap;

/// An episode with `frames` frames of `action` and `observation.state` (7-D each, as
/// ours: deltas and the pose they drive) moving smoothly, task 0, at 10 fps.
pub(crate) fn episode(index: u64, frames: usize, seed: u64) -> EpisodeSeries {
    let mut rng = crate::rng::SplitMix64::new(seed);
    let mut state = [0.0f32, 0.0, 0.05, 0.0, 0.0, 0.0, 0.5];
    let (mut states, mut actions) = (Vec::new(), Vec::new());
    let mut velocity = [0.0f32; 6];
    for t in 0..frames {
        for v in velocity.iter_mut() {
            *v = 0.8 * *v + 0.002 * (rng.next_f64() as f32 - 0.5);
        }
        let gripper = if (t / 15) % 2 == 0 { 1.0 } else { 0.0 };
        let mut action = [0.0f32; 7];
        action[..6].copy_from_slice(&velocity);
        action[6] = gripper;
        states.extend_from_slice(&state);
        actions.extend_from_slice(&action);
        for d in 0..6 {
            state[d] += action[d];
        }
        state[6] = 0.6 * gripper;
    }
    let mut features = BTreeMap::new();
    features.insert(
        "action".to_string(),
        Series {
            dims: 7,
            values: actions,
        },
    );
    features.insert(
        "observation.state".to_string(),
        Series {
            dims: 7,
            values: states,
        },
    );
    EpisodeSeries {
        episode: index,
        task: Some(0),
        timestamps_secs: (0..frames).map(|t| t as f64 / 10.0).collect(),
        features,
    }
}

pub(crate) fn dataset() -> LintDataset {
    let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect();
    LintDataset {
        fps: Some(10.0),
        features: vec![
            LintFeature {
                name: "action".into(),
                dims: 7,
                names: names(&[
                    "dx_m",
                    "dy_m",
                    "dz_m",
                    "droll_rad",
                    "dpitch_rad",
                    "dyaw_rad",
                    "gripper_open",
                ]),
            },
            LintFeature {
                name: "observation.state".into(),
                dims: 7,
                names: names(&[
                    "tip_x_m",
                    "tip_y_m",
                    "tip_z_m",
                    "tip_roll_rad",
                    "tip_pitch_rad",
                    "tip_yaw_rad",
                    "jaw_angle_rad",
                ]),
            },
        ],
        timestamp_f32: true,
        instructions: vec!["pick up the gauze".into()],
        gripper: Some(GripperEncoding::Continuous),
        ..LintDataset::default()
    }
}

pub(crate) fn episodes(count: u64, frames: usize) -> Vec<EpisodeSeries> {
    (0..count).map(|i| episode(i, frames, 100 + i)).collect()
}

/// The lint's findings and summaries on `episodes`.
pub(crate) fn run(
    dataset: &LintDataset,
    episodes: &[EpisodeSeries],
) -> crate::export::findings::Report {
    let findings = Findings::new(std::path::Path::new("/nonexistent"));
    lint(dataset, episodes, &[], "data", &findings);
    findings.into_report("lerobot-v3.0", Default::default())
}

/// The checks that reported (errors and warnings), by name.
pub(crate) fn fired(report: &crate::export::findings::Report) -> Vec<String> {
    let mut names: Vec<String> = report
        .errors
        .iter()
        .chain(&report.warnings)
        .map(|f| f.check.name().to_string())
        .collect();
    names.sort();
    names.dedup();
    names
}
