//! What `info --plot` draws of a dataset ([`crate::chart::plots::dataset_chart`]): each task's
//! episode lengths, and each state and action dimension's range, read episode by episode from
//! any [`EpisodeSource`] (memory: one episode).

use crate::episode::{FeatureKind, FeatureValue};
use crate::export::error::ExportError;
use crate::export::source::EpisodeSource;

/// A dataset's episode lengths by task (in order of first appearance) and its vectors' ranges.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Profile {
    /// (task, each of its episodes' frames).
    pub lengths: Vec<(String, Vec<u64>)>,
    /// (min, max) of each state dimension; empty without frames.
    pub state: Vec<(f64, f64)>,
    pub action: Vec<(f64, f64)>,
    /// Each dimension's name as the dataset gives it (info.json's `names`; empty: none).
    pub state_names: Vec<String>,
    pub action_names: Vec<String>,
}

fn widen(ranges: &mut Vec<(f64, f64)>, values: &[f32]) {
    if ranges.is_empty() {
        ranges.resize(values.len(), (f64::INFINITY, f64::NEG_INFINITY));
    }
    for (range, &value) in ranges.iter_mut().zip(values) {
        let value = f64::from(value);
        if value.is_finite() {
            *range = (range.0.min(value), range.1.max(value));
        }
    }
}

/// Reads every episode of `source` into its profile.
pub fn profile(source: &mut dyn EpisodeSource) -> Result<Profile, ExportError> {
    let mut profile = Profile::default();
    // Another tool's vectors are features of its own (not in the steps' state and action):
    // LeRobot's `observation.state` and `action`, found among the steps' other values.
    let info = source.info();
    let other_index = |name: &str| {
        info.features
            .iter()
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
            .position(|f| f.name == name)
    };
    let state_at = (!info.has(FeatureKind::State))
        .then(|| other_index("observation.state"))
        .flatten();
    let action_at = (!info.has(FeatureKind::Action))
        .then(|| other_index("action"))
        .flatten();
    let has_state = info.has(FeatureKind::State);
    let has_action = info.has(FeatureKind::Action);
    let names = |kind: FeatureKind, name: &str| {
        (info.features.iter())
            .find(|f| f.kind == kind || (f.kind == FeatureKind::Other && f.name == name))
            .map(|f| f.names.clone())
            .unwrap_or_default()
    };
    profile.state_names = names(FeatureKind::State, "observation.state");
    profile.action_names = names(FeatureKind::Action, "action");
    for episode in &mut *source {
        let episode = episode?;
        let meta = &episode.meta;
        let task = if meta.task_code.is_empty() {
            meta.instruction.clone()
        } else {
            meta.task_code.clone()
        };
        let frames = episode.steps.len() as u64;
        match profile.lengths.iter_mut().find(|(t, _)| *t == task) {
            Some((_, lengths)) => lengths.push(frames),
            None => profile.lengths.push((task, vec![frames])),
        }
        for step in &episode.steps {
            let other = |at: Option<usize>| match at.and_then(|k| step.other.get(k)) {
                Some(FeatureValue::Float32(values)) => Some(values.as_slice()),
                _ => None,
            };
            if has_state {
                widen(&mut profile.state, &step.state);
            } else if let Some(values) = other(state_at) {
                widen(&mut profile.state, values);
            }
            if has_action {
                widen(&mut profile.action, &step.action);
            } else if let Some(values) = other(action_at) {
                widen(&mut profile.action, values);
            }
        }
    }
    Ok(profile)
}

/// The profile's histograms (`bins` equal bins over every task's lengths, so panels compare)
/// and ranges, as the chart takes them.
pub fn chart_parts(
    profile: &Profile,
    bins: usize,
) -> (
    Vec<crate::chart::plots::Histogram>,
    Vec<(String, Vec<crate::chart::plots::Range>)>,
) {
    use crate::chart::plots::{Histogram, Range};
    let all = profile.lengths.iter().flat_map(|(_, l)| l.iter().copied());
    let low = all.clone().min().unwrap_or(0);
    let high = all.max().unwrap_or(0).max(low + 1);
    let bins = bins.max(1);
    let histograms = profile
        .lengths
        .iter()
        .map(|(task, lengths)| {
            let mut counts = vec![0u64; bins];
            for &length in lengths {
                let bin =
                    ((length - low) as usize * bins / (high - low + 1) as usize).min(bins - 1);
                counts[bin] += 1;
            }
            Histogram {
                label: format!("{task}: {} episodes", lengths.len()),
                counts,
                low: low as f64,
                high: high as f64,
            }
        })
        .collect();
    // Each dimension named as the dataset names it; dimensions drawn on one scale per unit
    // (the unit a name ends with: `tip_x_m`, `tip_yaw_rad`), so that centimetres are not
    // flattened by radians.
    let ranges = |name: &str, values: &[(f64, f64)], names: &[String]| {
        let mut groups: Vec<(String, Vec<Range>)> = Vec::new();
        for (i, &(min, max)) in values.iter().enumerate() {
            let label = names
                .get(i)
                .cloned()
                .unwrap_or_else(|| format!("{name}[{i}]"));
            let group = match unit_of(&label) {
                Some(unit) => format!("{name} ({unit})"),
                None => name.to_string(),
            };
            let range = Range { label, min, max };
            let index = match groups.iter().position(|(g, _)| *g == group) {
                Some(index) => index,
                None => {
                    groups.push((group, Vec::new()));
                    groups.len() - 1
                }
            };
            if min <= max {
                groups[index].1.push(range);
            }
        }
        if groups.is_empty() {
            groups.push((name.to_string(), Vec::new()));
        }
        groups
    };
    let mut groups = ranges("state", &profile.state, &profile.state_names);
    groups.extend(ranges("action", &profile.action, &profile.action_names));
    (histograms, groups)
}

/// The unit a dimension's name ends with (`tip_x_m`: metres), if it names one.
fn unit_of(name: &str) -> Option<&'static str> {
    let suffix = name.rsplit_once('_')?.1;
    [
        ("m", "m"),
        ("rad", "rad"),
        ("deg", "deg"),
        ("mm", "mm"),
        ("s", "s"),
    ]
    .iter()
    .find(|(s, _)| *s == suffix)
    .map(|(_, unit)| *unit)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_fall_in_bins_shared_by_every_task_and_ranges_keep_their_extremes() {
        let profile = Profile {
            lengths: vec![("T1-1".into(), vec![30, 30, 39]), ("T3-1".into(), vec![49])],
            state: vec![(-1.0, 2.0)],
            action: vec![(f64::INFINITY, f64::NEG_INFINITY)],
            ..Profile::default()
        };
        let (histograms, ranges) = chart_parts(&profile, 4);
        // [30, 49] in 4 bins of 5 frames: 30-34, 35-39, 40-44, 45-49.
        assert_eq!(histograms[0].counts, [2, 1, 0, 0]);
        assert_eq!(histograms[1].counts, [0, 0, 0, 1]);
        assert_eq!((histograms[0].low, histograms[0].high), (30.0, 49.0));
        assert_eq!(ranges[0].1.len(), 1);
        assert_eq!((ranges[0].1[0].min, ranges[0].1[0].max), (-1.0, 2.0));
        assert!(
            ranges[1].1.is_empty(),
            "a dimension never seen has no range"
        );
        let mut numbers = vec![(f64::INFINITY, f64::NEG_INFINITY); 2];
        widen(&mut numbers, &[1.0, f32::NAN]);
        widen(&mut numbers, &[-3.0, 2.0]);
        assert_eq!(numbers, [(-3.0, 1.0), (2.0, 2.0)]);
    }

    /// Another tool's LeRobot dataset: `observation.state` and `action` are its own features,
    /// in the steps' other values; their ranges are drawn from there.
    #[test]
    fn another_tools_state_and_action_are_profiled() {
        use crate::episode::{Dtype, Episode, EpisodeMeta, FeatureSpec, Step};
        let feature = |name: &str, size: usize| FeatureSpec {
            name: name.into(),
            dtype: Dtype::Float32,
            shape: vec![size],
            names: Vec::new(),
            kind: FeatureKind::Other,
            video: None,
            info: Default::default(),
        };
        let info = crate::export::info::DatasetInfo::from_surgvla_json(
            &serde_json::Value::Null,
            5,
            "r",
            vec![feature("observation.state", 2), feature("action", 1)],
        );
        let step = |state: [f32; 2], action: f32| Step {
            other: vec![
                FeatureValue::Float32(state.to_vec()),
                FeatureValue::Float32(vec![action]),
            ],
            ..Step::empty()
        };
        let episode = Episode {
            meta: EpisodeMeta::foreign(0, "lift".into()),
            steps: vec![step([0.0, 5.0], -1.0), step([2.0, 4.0], 3.0)],
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
        };
        struct One(Option<Episode>, crate::export::info::DatasetInfo);
        impl Iterator for One {
            type Item = Result<Episode, ExportError>;
            fn next(&mut self) -> Option<Self::Item> {
                self.0.take().map(Ok)
            }
        }
        impl EpisodeSource for One {
            fn info(&self) -> &crate::export::info::DatasetInfo {
                &self.1
            }
            fn len(&self) -> u64 {
                u64::from(self.0.is_some())
            }
            fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
                self.0.take().map(|_| Ok(()))
            }
        }
        let profiled = profile(&mut One(Some(episode), info)).expect("profile");
        assert_eq!(profiled.state, [(0.0, 2.0), (4.0, 5.0)]);
        assert_eq!(profiled.action, [(-1.0, 3.0)]);
        assert_eq!(profiled.lengths, [("lift".to_string(), vec![2])]);
    }

    #[test]
    fn dimensions_are_named_and_drawn_on_one_scale_per_unit() {
        let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let profile = Profile {
            state: vec![(0.5, 0.59), (0.0, 0.01), (-1.6, -1.5), (0.0, 0.7)],
            action: vec![(-0.01, 0.01), (0.0, 1.0)],
            state_names: names(&["tip_x_m", "tip_y_m", "tip_roll_rad", "jaw_angle_rad"]),
            action_names: names(&["dx_m", "gripper"]),
            ..Profile::default()
        };
        let (_, groups) = chart_parts(&profile, 4);
        let drawn: Vec<(&str, Vec<&str>)> = (groups.iter())
            .map(|(g, rows)| (g.as_str(), rows.iter().map(|r| r.label.as_str()).collect()))
            .collect();
        assert_eq!(
            drawn,
            [
                ("state (m)", vec!["tip_x_m", "tip_y_m"]),
                ("state (rad)", vec!["tip_roll_rad", "jaw_angle_rad"]),
                ("action (m)", vec!["dx_m"]),
                ("action", vec!["gripper"]),
            ]
        );
        // Without names: indices, one scale.
        let plain = Profile {
            state: vec![(0.0, 1.0), (2.0, 3.0)],
            ..Profile::default()
        };
        let (_, groups) = chart_parts(&plain, 4);
        assert_eq!(groups[0].0, "state");
        assert_eq!(groups[0].1[1].label, "state[1]");
    }
}
