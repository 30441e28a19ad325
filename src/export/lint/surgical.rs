//! What a robot's data needs and lerobot-doctor does not judge: actions in step with the state
//! they drive, unit quaternions without sign flips, a gripper inside its stated range, poses
//! that move no faster than a surgical robot can, positions in the unit their names declare,
//! and timestamps relative to the episode (epoch seconds in float32 are 128 s coarse).
//!
//! Dimensions are recognised by their names (info.json's `names`): `x`, `y`, `z` with a common
//! prefix and suffix are a position (`tip_x_m`, `object_0.x`, `psm1.x`), metres when the suffix
//! says `_m` or a quaternion follows (a ROS pose), millimetres when it says `mm`; `qx`, `qy`,
//! `qz`, `qw` (or `quat_*`, `orientation.*`) are a quaternion.

use super::series::{EpisodeSeries, Lint, LintDataset, LintFeature, Series, plural, with_feature};
use crate::episode::GripperEncoding;
use crate::export::check::Check;

/// Most frames an action may lead or lag the state it drives before it is out of step.
pub const LAG_FRAMES: i64 = 3;
/// The correlation the best offset must reach to be called a lag, and how many times less of
/// the state's steps it must leave unexplained (1 - r^2) than offset 0 does (plus 0.02).
pub const LAG_CORRELATION: f64 = 0.5;
pub const LAG_UNEXPLAINED_RATIO: f64 = 2.0;
/// A quaternion whose norm is this far from 1 is not a rotation.
pub const QUATERNION_NORM_TOLERANCE: f64 = 0.01;
/// Consecutive unit quaternions whose dot product is below this flip sign (the same rotation,
/// the other hemisphere: an interpolation or a normaliser sees a full turn).
pub const SIGN_FLIP_DOT: f64 = -0.9;
/// Fastest a surgical tool tip moves (m/s): a step further than this allows is a jump.
pub const TIP_SPEED_M_PER_S: f64 = 0.25;
/// Positions declared in metres larger than this are millimetres; declared in millimetres and
/// all smaller than this (in mm), metres.
pub const METRES_AT_MOST: f64 = 5.0;
pub const MILLIMETRES_AT_LEAST: f64 = 0.5;
/// Timestamps beyond this many seconds are epoch-scale (lerobot's are from the episode start).
pub const EPOCH_SECS: f64 = 1e8;

pub(super) fn check(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    lag(lint, dataset, episodes);
    lint.done(
        Check::ActionLag,
        true,
        "each action best predicts the state's next step",
    );
    for feature in &dataset.features {
        for group in quaternions(feature) {
            norms(lint, feature, group, episodes);
        }
    }
    lint.done(Check::Quaternion, true, "every quaternion has unit norm");
    for feature in &dataset.features {
        for group in quaternions(feature) {
            flips(lint, feature, group, episodes);
        }
    }
    lint.done(
        Check::QuaternionSign,
        false,
        "no quaternion flips sign between frames",
    );
    gripper(lint, dataset, episodes);
    lint.done(
        Check::GripperRange,
        true,
        "every gripper value lies in its stated range",
    );
    jumps(lint, dataset, episodes);
    lint.done(
        Check::PoseJump,
        false,
        "no tool-tip position moves faster than 0.25 m/s",
    );
    for feature in &dataset.features {
        units(lint, feature, episodes);
    }
    lint.done(
        Check::Units,
        true,
        "positions are in the units their names declare",
    );
    epoch(lint, dataset, episodes);
    lint.done(
        Check::EpochTimestamps,
        true,
        "timestamps count from the episode's start",
    );
}

/// Splits a name at one of `axes` that its siblings replace: (prefix, axis, suffix).
fn axis_of<'a>(name: &'a str, axes: &[char]) -> Vec<(&'a str, char, &'a str)> {
    name.char_indices()
        .filter(|(_, c)| axes.contains(c))
        .map(|(i, c)| (&name[..i], c, &name[i + c.len_utf8()..]))
        .collect()
}

/// Position triplets: (first dimension, unit) where the unit is Some("m") or Some("mm").
fn positions(feature: &LintFeature) -> Vec<(usize, Option<&'static str>)> {
    let names = &feature.names;
    let mut found = Vec::new();
    let quaternion_starts: Vec<usize> = quaternions(feature).into_iter().map(|q| q[0]).collect();
    for i in 0..names.len().saturating_sub(2) {
        for (prefix, axis, suffix) in axis_of(&names[i], &['x']) {
            let _ = axis;
            let same = |j: usize, a: &str| names[i + j] == format!("{prefix}{a}{suffix}");
            let is_quaternion_part = prefix.ends_with('q') || prefix.contains("quat");
            if same(1, "y") && same(2, "z") && !is_quaternion_part {
                let unit = if suffix.contains("mm") {
                    Some("mm")
                } else if suffix.ends_with("_m")
                    || suffix.ends_with(".m")
                    || quaternion_starts.contains(&(i + 3))
                {
                    // A pose (x, y, z, qx, qy, qz, qw) is in ROS's metres.
                    Some("m")
                } else {
                    None
                };
                found.push((i, unit));
                break;
            }
        }
    }
    found
}

/// Quaternion groups: the dimensions of x, y, z, w, in that order.
fn quaternions(feature: &LintFeature) -> Vec<[usize; 4]> {
    let names = &feature.names;
    let mut found = Vec::new();
    for i in 0..names.len() {
        for (prefix, _, suffix) in axis_of(&names[i], &['x']) {
            let quaternion_like = prefix.ends_with('q')
                || prefix.contains("quat")
                || prefix.contains("orientation")
                || prefix.contains("rot");
            if !quaternion_like {
                continue;
            }
            let find = |a: char| {
                let wanted = format!("{prefix}{a}{suffix}");
                (i.saturating_sub(3)..(i + 4).min(names.len())).find(|&j| names[j] == wanted)
            };
            if let (Some(y), Some(z), Some(w)) = (find('y'), find('z'), find('w')) {
                found.push([i, y, z, w]);
                break;
            }
        }
    }
    found
}

fn norms(lint: &mut Lint<'_>, feature: &LintFeature, q: [usize; 4], episodes: &[EpisodeSeries]) {
    for (episode, series) in with_feature(feature, episodes) {
        let mut bad = (0usize, None);
        for (t, row) in series.rows().enumerate() {
            let values = q.map(|d| f64::from(row[d]));
            if values.iter().all(|v| *v == 0.0) || values.iter().any(|v| !v.is_finite()) {
                continue; // an absent object's padding; NaN is the finite check's
            }
            let norm = values.iter().map(|v| v * v).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                bad.0 += 1;
                bad.1.get_or_insert((t, norm));
            }
        }
        if let (count, Some((t, norm))) = bad {
            lint.flag(
                episode.episode,
                Some(t as u64),
                format!(
                    "{}..{} has norm {norm:.4}, not 1 ({count} frame{})",
                    feature.label(q[0]),
                    feature.names.get(q[3]).map_or("", |s| s.as_str()),
                    plural(count)
                ),
            );
        }
    }
}

fn flips(lint: &mut Lint<'_>, feature: &LintFeature, q: [usize; 4], episodes: &[EpisodeSeries]) {
    for (episode, series) in with_feature(feature, episodes) {
        let unit = |t: usize| {
            let v = q.map(|d| f64::from(series.row(t)[d]));
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            (norm > 0.5 && norm.is_finite()).then(|| v.map(|x| x / norm))
        };
        let mut count = 0usize;
        let mut first = None;
        for t in 1..series.frames() {
            if let (Some(a), Some(b)) = (unit(t - 1), unit(t)) {
                let dot: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
                if dot < SIGN_FLIP_DOT {
                    count += 1;
                    first.get_or_insert(t);
                }
            }
        }
        if let Some(t) = first {
            lint.flag(
                episode.episode,
                Some(t as u64),
                format!(
                    "the quaternion at {} flips sign ({count} time{}): keep consecutive quaternions in one hemisphere",
                    feature.label(q[0]),
                    plural(count)
                ),
            );
        }
    }
}

/// The correlation of action dimensions with the state's next steps, at offsets
/// -[`LAG_FRAMES`]..=[`LAG_FRAMES`], for actions that are steps (`a[t]` against
/// `s[t+1+k] - s[t+k]`) and actions that are targets (`a[t] - a[t-1]` likewise).
fn lag(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let (Some(action), Some(state)) = (
        dataset.feature("action"),
        dataset.feature("observation.state"),
    ) else {
        return;
    };
    let pick = |f: &LintFeature| -> Option<usize> {
        match positions(f).first() {
            Some((d, _)) => Some(*d),
            None if f.dims >= 3 && f.names.is_empty() => Some(0),
            None => None,
        }
    };
    let (Some(a0), Some(s0)) = (pick(action), pick(state)) else {
        return;
    };
    let offsets: Vec<i64> = (-LAG_FRAMES..=LAG_FRAMES).collect();
    // [mode][offset][dim] -> sums (n, x, y, xx, yy, xy)
    let mut sums = vec![vec![[[0.0f64; 6]; 3]; offsets.len()]; 2];
    for episode in episodes {
        let (Some(a), Some(s)) = (
            episode.features.get("action"),
            episode.features.get("observation.state"),
        ) else {
            continue;
        };
        accumulate(&mut sums, (a, a0), (s, s0), &offsets);
    }
    let correlation = |mode: usize, k: usize| {
        (0..3)
            .map(|d| {
                let [n, x, y, xx, yy, xy] = sums[mode][k][d];
                let cov = xy / n - (x / n) * (y / n);
                let var = (xx / n - (x / n).powi(2)) * (yy / n - (y / n).powi(2));
                if n < 10.0 || var <= 0.0 {
                    0.0
                } else {
                    cov / var.sqrt()
                }
            })
            .sum::<f64>()
            / 3.0
    };
    let zero = LAG_FRAMES as usize;
    let best = (0..2)
        .flat_map(|mode| (0..offsets.len()).map(move |k| (mode, k)))
        .map(|(mode, k)| (mode, k, correlation(mode, k)))
        .max_by(|a, b| a.2.total_cmp(&b.2));
    let Some((mode, k, r)) = best else {
        return;
    };
    let at_zero = correlation(mode, zero);
    let unexplained = |r: f64| 1.0 - r.clamp(-1.0, 1.0).powi(2);
    if k != zero
        && r > LAG_CORRELATION
        && unexplained(at_zero) > LAG_UNEXPLAINED_RATIO * unexplained(r) + 0.02
    {
        let offset = offsets[k];
        let how = if offset < 0 { "lags" } else { "leads" };
        lint.note(
            true,
            format!(
                "action {how} the state by {} frame{}: {}[{a0}..] best predicts the state's step {offset:+} frames away (correlation {r:.2}, against {at_zero:.2} in step); a trainer would learn the wrong action for each observation",
                offset.abs(),
                if offset.abs() == 1 { "" } else { "s" },
                action.name
            ),
        );
    }
}

type LagSums = Vec<Vec<[[f64; 6]; 3]>>;

fn accumulate(
    sums: &mut LagSums,
    (a, a0): (&Series, usize),
    (s, s0): (&Series, usize),
    offsets: &[i64],
) {
    let frames = a.frames().min(s.frames()) as i64;
    if a0 + 3 > a.dims || s0 + 3 > s.dims {
        return;
    }
    for (k, &offset) in offsets.iter().enumerate() {
        for t in 1..frames {
            let j = t + offset;
            if j < 0 || j + 1 >= frames {
                continue;
            }
            let (t, j) = (t as usize, j as usize);
            let step = |d: usize| f64::from(s.row(j + 1)[s0 + d]) - f64::from(s.row(j)[s0 + d]);
            let as_step = |d: usize| f64::from(a.row(t)[a0 + d]);
            let as_target = |d: usize| as_step(d) - f64::from(a.row(t - 1)[a0 + d]);
            for (mode, x_of) in [&as_step as &dyn Fn(usize) -> f64, &as_target]
                .iter()
                .enumerate()
            {
                for (d, cell) in sums[mode][k].iter_mut().enumerate() {
                    let (x, y) = (x_of(d), step(d));
                    if !(x.is_finite() && y.is_finite()) {
                        continue;
                    }
                    for (slot, v) in cell.iter_mut().zip([1.0, x, y, x * x, y * y, x * y]) {
                        *slot += v;
                    }
                }
            }
        }
    }
}

/// Our datasets' gripper action against the range its encoding states.
fn gripper(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let Some(encoding) = dataset.gripper else {
        return;
    };
    let Some(action) = dataset.feature("action") else {
        return;
    };
    let Some(d) = (action.names.iter().position(|n| n.contains("gripper")))
        .or((action.dims == 7).then_some(6))
    else {
        return;
    };
    let (low, high) = match encoding {
        GripperEncoding::Continuous => (0.0, 1.0),
        GripperEncoding::Pulse => (-1.0, 1.0),
    };
    for episode in episodes {
        let Some(series) = episode.features.get("action").filter(|s| d < s.dims) else {
            continue;
        };
        let outside: Vec<(usize, f32)> = (series.column(d).enumerate())
            .filter(|(_, v)| v.is_finite() && !(low..=high).contains(v))
            .collect();
        if let Some((t, v)) = outside.first() {
            lint.flag(
                episode.episode,
                Some(*t as u64),
                format!(
                    "{} is {v}, outside [{low}, {high}] ({encoding:?} encoding; {} frame{})",
                    action.label(d),
                    outside.len(),
                    plural(outside.len())
                ),
            );
        }
    }
}

/// The robot's own positions (state features) moving further in a step than
/// [`TIP_SPEED_M_PER_S`] allows.
fn jumps(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let Some(fps) = dataset.fps.filter(|f| *f > 0.0) else {
        return;
    };
    let limit_m = TIP_SPEED_M_PER_S / fps;
    for feature in dataset
        .features
        .iter()
        .filter(|f| f.name == "observation.state")
    {
        for (d, unit) in positions(feature) {
            let scale = match unit {
                Some("m") => 1.0,
                Some("mm") => 1e-3,
                _ => continue,
            };
            for episode in episodes {
                let Some(series) = episode
                    .features
                    .get(&feature.name)
                    .filter(|s| d + 3 <= s.dims)
                else {
                    continue;
                };
                let step = |t: usize| {
                    (0..3)
                        .map(|i| {
                            let v = f64::from(series.row(t)[d + i])
                                - f64::from(series.row(t - 1)[d + i]);
                            v * v
                        })
                        .sum::<f64>()
                        .sqrt()
                        * scale
                };
                let far: Vec<(usize, f64)> = (1..series.frames())
                    .map(|t| (t, step(t)))
                    .filter(|(_, m)| *m > limit_m)
                    .collect();
                if let Some((t, m)) = far.first() {
                    lint.flag(
                        episode.episode,
                        Some(*t as u64),
                        format!(
                            "{} moves {:.1} mm in one step ({:.2} m/s; a tool tip moves at most {TIP_SPEED_M_PER_S} m/s)",
                            feature.label(d),
                            m * 1e3,
                            m * fps
                        ),
                    );
                }
            }
        }
    }
}

fn units(lint: &mut Lint<'_>, feature: &LintFeature, episodes: &[EpisodeSeries]) {
    for (d, unit) in positions(feature) {
        let largest = episodes
            .iter()
            .filter_map(|e| e.features.get(&feature.name))
            .filter(|s| d + 3 <= s.dims)
            .flat_map(|s| s.rows().flat_map(move |row| row[d..d + 3].to_vec()))
            .map(|v| f64::from(v).abs())
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        let wrong = match unit {
            Some("m") if largest > METRES_AT_MOST => Some(("metres", "millimetres")),
            Some("mm") if largest > 0.0 && largest < MILLIMETRES_AT_LEAST => {
                Some(("millimetres", "metres"))
            }
            _ => None,
        };
        if let Some((declared, looks)) = wrong {
            lint.note(
                true,
                format!(
                    "{}..: declared in {declared}, its values reach {largest:.4}: {looks}?",
                    feature.label(d)
                ),
            );
        }
    }
}

fn epoch(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    for episode in episodes {
        let Some((t, secs)) = (episode.timestamps_secs.iter().enumerate())
            .find(|(_, s)| s.is_finite() && s.abs() > EPOCH_SECS)
        else {
            continue;
        };
        let coarse = if dataset.timestamp_f32 {
            format!(
                "; as float32 they are {} s coarse",
                2f64.powi((secs.abs().log2().floor() as i32) - 23)
            )
        } else {
            String::new()
        };
        lint.flag(
            episode.episode,
            Some(t as u64),
            format!(
                "timestamp {secs} s is epoch-scale: lerobot's timestamps count from the episode's start{coarse}"
            ),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dataset, episodes, fired, run};
    use super::*;

    #[test]
    fn names_say_which_dimensions_are_positions_and_quaternions() {
        let feature = |names: &[&str]| LintFeature {
            name: "f".into(),
            dims: names.len(),
            names: names.iter().map(|s| s.to_string()).collect(),
        };
        let pose = feature(&[
            "psm1.x", "psm1.y", "psm1.z", "psm1.qx", "psm1.qy", "psm1.qz", "psm1.qw", "psm1.jaw",
        ]);
        assert_eq!(positions(&pose), [(0, Some("m"))]);
        assert_eq!(quaternions(&pose), [[3, 4, 5, 6]]);
        let ours = dataset();
        assert_eq!(positions(&ours.features[1]), [(0, Some("m"))]);
        assert_eq!(positions(&ours.features[0]), [(0, Some("m"))]);
        assert!(quaternions(&ours.features[1]).is_empty());
        assert_eq!(
            positions(&feature(&["x_mm", "y_mm", "z_mm"])),
            [(0, Some("mm"))]
        );
    }

    #[test]
    fn an_action_shifted_against_the_state_is_out_of_step() {
        let dataset = dataset();
        let clean = episodes(12, 110);
        assert!(fired(&run(&dataset, &clean)).is_empty());
        for shift in [1usize, 2] {
            let mut shifted = clean.clone();
            for episode in &mut shifted {
                let series = episode.features.get_mut("action").unwrap();
                let len = series.values.len();
                series.values.copy_within(0..len - shift * 7, shift * 7);
            }
            let report = run(&dataset, &shifted);
            let lag: Vec<_> = (report.errors.iter())
                .filter(|f| f.check == "action-lag")
                .collect();
            assert_eq!(lag.len(), 1, "shift {shift}: {report:#?}");
            assert!(
                lag[0].message.contains(&format!("by {shift} frame")),
                "{}",
                lag[0].message
            );
        }
    }

    #[test]
    fn planted_pose_unit_gripper_and_time_defects_fire_their_checks() {
        let dataset = dataset();
        let clean = episodes(12, 110);
        let plant = |f: &dyn Fn(&mut Vec<super::super::series::EpisodeSeries>)| {
            let mut eps = clean.clone();
            f(&mut eps);
            fired(&run(&dataset, &eps))
        };
        assert!(
            plant(&|eps| {
                let s = eps[2].features.get_mut("observation.state").unwrap();
                for t in 30..60 {
                    s.values[t * 7] += 0.08;
                }
            })
            .contains(&"pose-jump".to_string())
        );
        assert!(
            plant(&|eps| {
                for e in eps.iter_mut() {
                    let s = e.features.get_mut("observation.state").unwrap();
                    for t in 0..60 {
                        for d in 0..3 {
                            s.values[t * 7 + d] *= 1000.0;
                            s.values[t * 7 + d] += 10.0;
                        }
                    }
                }
            })
            .contains(&"units".to_string())
        );
        assert_eq!(
            plant(&|eps| eps[1].features.get_mut("action").unwrap().values[10 * 7 + 6] = 1.5),
            ["gripper-range"]
        );
        assert_eq!(
            plant(&|eps| {
                for t in eps[0].timestamps_secs.iter_mut() {
                    *t += 1.7e9;
                }
            }),
            ["epoch-timestamps"]
        );
    }

    #[test]
    fn a_non_unit_or_flipped_quaternion_is_named_and_padding_is_not() {
        let mut dataset = dataset();
        dataset.features.push(LintFeature {
            name: "observation.environment_state".into(),
            dims: 14,
            names: ["x", "y", "z", "qx", "qy", "qz", "qw"]
                .iter()
                .flat_map(|n| [format!("object_0.{n}")])
                .chain(
                    ["x", "y", "z", "qx", "qy", "qz", "qw"]
                        .iter()
                        .map(|n| format!("object_1.{n}")),
                )
                .collect(),
        });
        let with = |values: &dyn Fn(usize) -> [f32; 7]| {
            let mut eps = episodes(12, 110);
            for e in eps.iter_mut() {
                let mut v = Vec::new();
                for t in 0..60 {
                    v.extend_from_slice(&values(t));
                    v.extend_from_slice(&[0.0; 7]); // an absent object
                }
                e.features.insert(
                    "observation.environment_state".into(),
                    Series {
                        dims: 14,
                        values: v,
                    },
                );
            }
            let mut names = fired(&run(&dataset, &eps));
            names.retain(|n| n.starts_with("quaternion"));
            names
        };
        let turning = |t: usize| {
            let a = t as f32 * 0.01;
            [0.01, 0.02, 0.03, 0.0, 0.0, a.sin(), a.cos()]
        };
        assert!(with(&turning).is_empty());
        assert_eq!(
            with(&|t| {
                let mut q = turning(t);
                q[6] *= 1.1;
                q
            }),
            ["quaternion"]
        );
        assert_eq!(
            with(&|t| {
                let mut q = turning(t);
                if t >= 30 {
                    for v in &mut q[3..] {
                        *v = -*v;
                    }
                }
                q
            }),
            ["quaternion-sign"]
        );
    }
}
