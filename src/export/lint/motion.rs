//! What lerobot-doctor 0.2.0 judges of the numbers (its "actions", "statistics" and
//! "anomalies" groups), with its thresholds: actions frozen for a stretch of an episode, sudden
//! action jumps, values clipped at a bound, dimensions stuck within episodes or constant across
//! the dataset, outliers, drift between a task's first and last episodes, duplicate episodes.
//! Where doctor misjudges a multi-task dataset (drift between one task's episodes and the
//! next's) the comparison is made within each task; discrete dimensions (a gripper's 0/1) are
//! not called clipped.

use super::series::{EpisodeSeries, Lint, LintDataset, is_action, mean_std, plural};
use crate::export::check::Check;
use std::collections::BTreeMap;

/// An episode whose actions repeat unchanged for this share of its frames (doctor: 5 %).
pub const FROZEN_SHARE: f64 = 0.05;
/// An action step whose change, in the dataset's standard deviations of steps and averaged over
/// dimensions, exceeds this is a jump (doctor: 8).
pub const JUMP_SIGMAS: f64 = 8.0;
/// A dimension with this share of its values at its minimum or maximum is clipped (doctor
/// warns at 50 %, fails at 99 %).
pub const CLIPPED_SHARE: f64 = 0.5;
/// A dimension unchanged for this share of an episode's steps in this share of the episodes is
/// stuck (doctor: 80 % and 80 %).
pub const STUCK_SHARE: f64 = 0.8;
/// A value this many standard deviations from its dimension's mean is an outlier (doctor: 10).
pub const OUTLIER_SIGMAS: f64 = 10.0;
/// A task's last quarter of episodes whose mean lies this many of its first quarter's standard
/// deviations away has drifted (doctor: 3, over the whole dataset).
pub const DRIFT_SIGMAS: f64 = 3.0;
/// Episodes whose first and last ten actions and length agree within this are duplicates
/// (doctor's tolerance).
pub const DUPLICATE_TOLERANCE: f64 = 1e-6;

pub(super) fn check(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let actions: Vec<&str> = (dataset.features.iter())
        .filter(|f| is_action(&f.name))
        .map(|f| f.name.as_str())
        .collect();
    for name in &actions {
        frozen(lint, dataset, name, episodes);
    }
    lint.done(
        Check::FrozenAction,
        false,
        "no episode repeats its actions unchanged for 5 % of its frames",
    );
    for name in &actions {
        jumps(lint, name, episodes);
    }
    lint.done(
        Check::ActionJump,
        false,
        "no action step jumps 8 standard deviations of the dataset's steps",
    );
    for feature in dataset.features.iter().filter(|f| is_action(&f.name)) {
        clipped(lint, feature, episodes);
    }
    lint.done(
        Check::Clipping,
        false,
        "no action dimension sits at its minimum or maximum for half its values",
    );
    for feature in dataset.features.iter().filter(|f| is_learned(&f.name)) {
        stuck(lint, dataset, feature, episodes);
    }
    lint.done(
        Check::StuckDimension,
        false,
        "no action or state dimension is stuck in most episodes",
    );
    for feature in dataset.features.iter().filter(|f| is_learned(&f.name)) {
        constant(lint, feature, episodes);
    }
    lint.done(
        Check::Constant,
        false,
        "every dimension varies across the dataset",
    );
    for feature in dataset.features.iter().filter(|f| is_learned(&f.name)) {
        outliers(lint, feature, episodes);
    }
    lint.done(
        Check::Outliers,
        false,
        "no value lies 10 standard deviations from its dimension's mean",
    );
    drift(lint, dataset, episodes);
    lint.done(
        Check::Drift,
        false,
        "no task's last episodes drift 3 standard deviations from its first",
    );
    duplicates(lint, episodes);
    lint.done(
        Check::DuplicateEpisodes,
        false,
        "no two episodes are duplicates",
    );
}

/// Whether a dimension takes at most three values (a gripper's 0/1 or -1/0/1).
fn is_discrete(values: impl Iterator<Item = f64>) -> bool {
    let mut distinct: Vec<f64> = Vec::new();
    for v in values {
        if !distinct.contains(&v) {
            distinct.push(v);
            if distinct.len() > 3 {
                return false;
            }
        }
    }
    true
}

/// Whether an action dimension's name says it is a step (`dx_m`, `delta_x`), not a target.
fn is_step(name: &str) -> bool {
    name.contains("delta") || (name.starts_with('d') && !name.contains("gripper"))
}

/// What a policy learns and is conditioned on: actions and the robot's state (not the
/// simulator's privileged object poses, heavy-tailed by nature: an object knocked over once).
fn is_learned(name: &str) -> bool {
    is_action(name) || (name.contains("state") && !name.contains("environment"))
}

/// An action smaller than this commands nothing (a planner's rounding: 4e-16).
const COMMAND_AT_LEAST: f32 = 1e-7;

/// The smallest spread drift is measured against (a dimension nearly constant in a task's
/// first episodes moves "many deviations" by rounding alone).
const SCALE_FLOOR: f64 = 1e-3;

/// The longest run of frames equal to the one before, per episode; a hold is no freeze: a
/// step action of zero motion, or any action while the robot's pose stays put.
fn frozen(lint: &mut Lint<'_>, dataset: &LintDataset, name: &str, episodes: &[EpisodeSeries]) {
    let grippers = |feature: Option<&super::series::LintFeature>| -> Vec<usize> {
        feature.map_or(Vec::new(), |f| {
            (f.names.iter().enumerate())
                .filter(|(_, n)| n.contains("gripper") || n.contains("jaw"))
                .map(|(d, _)| d)
                .collect()
        })
    };
    let action_grippers = grippers(dataset.feature(name));
    let state_grippers = grippers(dataset.feature("observation.state"));
    for episode in episodes {
        let Some(series) = episode.features.get(name) else {
            continue;
        };
        let frames = series.frames();
        if frames < 2 {
            continue;
        }
        let state = episode.features.get("observation.state");
        let holding = |t: usize| {
            let zero_motion = (series.row(t).iter().enumerate())
                .all(|(d, v)| *v == 0.0 || action_grippers.contains(&d));
            let still = state.filter(|s| t < s.frames()).is_some_and(|s| {
                (s.row(t).iter().zip(s.row(t - 1)).enumerate())
                    .all(|(d, (a, b))| (a - b).abs() < 1e-5 || state_grippers.contains(&d))
            });
            zero_motion || still
        };
        // Step actions repeated while the state follows them: a move at a capped speed.
        let steps: Vec<usize> = dataset.feature(name).map_or(Vec::new(), |f| {
            (0..f.dims.min(3))
                .filter(|&d| f.names.get(d).is_some_and(|n| is_step(n)))
                .collect()
        });
        let followed = |from: usize, to: usize| {
            let Some(state) = state.filter(|s| to + 1 < s.frames() && s.dims >= 3) else {
                return false;
            };
            steps.len() == 3
                && steps.iter().all(|&d| {
                    let commanded: f64 = (from..=to).map(|t| f64::from(series.row(t)[d])).sum();
                    let moved = f64::from(state.row(to + 1)[d]) - f64::from(state.row(from)[d]);
                    (moved - commanded).abs() <= 0.5 * commanded.abs() + 1e-4
                })
        };
        // Runs of repeats (start frame, repeats), each judged whole; the longest unexcused.
        let mut runs: Vec<(usize, usize)> = Vec::new();
        for t in 1..frames {
            if series.row(t) == series.row(t - 1) && !holding(t) {
                match runs.last_mut() {
                    Some((start, repeats)) if *start + *repeats == t - 1 => *repeats += 1,
                    _ => runs.push((t - 1, 1)),
                }
            }
        }
        let worst = (runs.into_iter())
            .filter(|&(start, repeats)| {
                repeats as f64 / frames as f64 >= FROZEN_SHARE && !followed(start, start + repeats)
            })
            .max_by_key(|&(start, repeats)| (repeats, std::cmp::Reverse(start)));
        if let Some((start, repeats)) = worst {
            lint.flag(
                episode.episode,
                Some(start as u64),
                format!(
                    "{name} repeats unchanged for {} consecutive frames ({:.0} % of the episode)",
                    repeats + 1,
                    repeats as f64 / frames as f64 * 100.0
                ),
            );
        }
    }
}

/// Steps whose change, averaged over dimensions in units of the dataset's standard deviation of
/// steps, exceeds [`JUMP_SIGMAS`].
fn jumps(lint: &mut Lint<'_>, name: &str, episodes: &[EpisodeSeries]) {
    let with: Vec<(&EpisodeSeries, &super::series::Series)> = episodes
        .iter()
        .filter_map(|e| e.features.get(name).map(|s| (e, s)))
        .filter(|(_, s)| s.frames() >= 3)
        .collect();
    let Some(dims) = with.first().map(|(_, s)| s.dims) else {
        return;
    };
    let sigma: Vec<f64> = (0..dims)
        .map(|d| {
            let steps = with.iter().flat_map(|(_, s)| {
                (1..s.frames()).map(move |t| f64::from(s.row(t)[d]) - f64::from(s.row(t - 1)[d]))
            });
            match mean_std(steps) {
                Some((_, std, _)) if std > 0.0 => std,
                _ => 1.0,
            }
        })
        .collect();
    for (episode, series) in with {
        let mut count = 0;
        let mut first = None;
        for t in 1..series.frames() {
            let (now, before) = (series.row(t), series.row(t - 1));
            let z: f64 = (0..dims)
                .map(|d| (f64::from(now[d]) - f64::from(before[d])).abs() / sigma[d])
                .sum::<f64>()
                / dims as f64;
            if z > JUMP_SIGMAS {
                count += 1;
                first.get_or_insert((t, z));
            }
        }
        if let Some((t, z)) = first {
            lint.flag(
                episode.episode,
                Some(t as u64),
                format!(
                    "{name} jumps {z:.1} standard deviations of the dataset's steps ({count} such step{})",
                    plural(count)
                ),
            );
        }
    }
}

/// Every value of dimension `d` of `name`, over the dataset.
fn dimension<'a>(
    episodes: &'a [EpisodeSeries],
    name: &'a str,
    d: usize,
) -> impl Iterator<Item = f64> + 'a {
    episodes
        .iter()
        .filter_map(move |e| e.features.get(name))
        .filter(move |s| d < s.dims)
        .flat_map(move |s| s.column(d).map(f64::from))
        .filter(|v| v.is_finite())
}

fn clipped(lint: &mut Lint<'_>, feature: &super::series::LintFeature, episodes: &[EpisodeSeries]) {
    for d in 0..feature.dims {
        let (mut min, mut max, mut n) = (f64::INFINITY, f64::NEG_INFINITY, 0usize);
        for v in dimension(episodes, &feature.name, d) {
            min = min.min(v);
            max = max.max(v);
            n += 1;
        }
        // A discrete dimension (a gripper's 0/1, -1/0/1) is at its bounds by design.
        if n <= 10 || min == max || is_discrete(dimension(episodes, &feature.name, d)) {
            continue;
        }
        let at_min = dimension(episodes, &feature.name, d)
            .filter(|v| *v == min)
            .count();
        let at_max = dimension(episodes, &feature.name, d)
            .filter(|v| *v == max)
            .count();
        for (count, bound, value) in [(at_min, "minimum", min), (at_max, "maximum", max)] {
            let share = count as f64 / n as f64;
            if share > CLIPPED_SHARE {
                lint.note(
                    false,
                    format!(
                        "{}: {:.1} % of its values sit at its {bound} {value}: clipped?",
                        feature.label(d),
                        share * 100.0
                    ),
                );
            }
        }
    }
}

/// Dimensions unchanged over most steps of most episodes. A state dimension that has an
/// action dimension of its own (the same number of dimensions) is stuck only where it was
/// commanded to move (a step action non-zero, a target action changed) and did not: an unused
/// degree of freedom is not a stuck actuator.
fn stuck(
    lint: &mut Lint<'_>,
    dataset: &LintDataset,
    feature: &super::series::LintFeature,
    episodes: &[EpisodeSeries],
) {
    let action = dataset
        .feature("action")
        .filter(|a| feature.name == "observation.state" && a.dims == feature.dims);
    let steps: Vec<bool> = (0..feature.dims)
        .map(|d| action.is_some_and(|a| a.names.get(d).is_some_and(|n| is_step(n))))
        .collect();
    let discrete: Vec<bool> = (0..feature.dims)
        .map(|d| is_discrete(dimension(episodes, &feature.name, d)))
        .collect();
    let mut per_dim = vec![0usize; feature.dims];
    let mut counted = 0usize;
    for episode in episodes {
        let Some(series) = episode.features.get(&feature.name) else {
            continue;
        };
        let frames = series.frames();
        if frames < 12 || series.dims != feature.dims {
            continue;
        }
        let commands = action.and_then(|_| episode.features.get("action"));
        counted += 1;
        for (d, stuck) in per_dim.iter_mut().enumerate() {
            let unchanged = |t: usize| series.row(t)[d] == series.row(t - 1)[d];
            let share = match commands.filter(|a| a.frames() >= frames) {
                Some(a) => {
                    let commanded: Vec<usize> = (2..frames)
                        .filter(|&t| {
                            let command = if steps[d] {
                                a.row(t - 1)[d]
                            } else {
                                a.row(t - 1)[d] - a.row(t - 2)[d]
                            };
                            command.abs() > COMMAND_AT_LEAST
                        })
                        .collect();
                    if commanded.len() < 5 {
                        continue;
                    }
                    commanded.iter().filter(|&&t| unchanged(t)).count() as f64
                        / commanded.len() as f64
                }
                None => {
                    let first = series.row(0)[d];
                    if series.column(d).all(|v| v == first) || discrete[d] {
                        continue; // constant: the constant check's; discrete: a gripper's
                    }
                    (1..frames).filter(|&t| unchanged(t)).count() as f64 / (frames - 1) as f64
                }
            };
            if share > STUCK_SHARE {
                *stuck += 1;
            }
        }
    }
    for (d, stuck) in per_dim.into_iter().enumerate() {
        if counted > 0 && stuck as f64 > counted as f64 * STUCK_SHARE {
            let how = if action.is_some() {
                "does not move when commanded to"
            } else {
                "is unchanged"
            };
            lint.note(
                false,
                format!(
                    "{}: {how} over 80 % of the steps in {stuck} of {counted} episodes: a stuck actuator or an unused degree of freedom?",
                    feature.label(d)
                ),
            );
        }
    }
}

fn constant(lint: &mut Lint<'_>, feature: &super::series::LintFeature, episodes: &[EpisodeSeries]) {
    let constant: Vec<String> = (0..feature.dims)
        .filter_map(|d| {
            let mut values = dimension(episodes, &feature.name, d);
            let first = values.next()?;
            values
                .all(|v| v == first)
                .then(|| format!("{} = {first}", feature.label(d)))
        })
        .collect();
    if constant.is_empty() {
        return;
    }
    let message = if constant.len() == feature.dims && feature.dims > 1 {
        format!(
            "{}: all {} dimensions are constant across the dataset: a broken sensor or an unused feature?",
            feature.name, feature.dims
        )
    } else {
        let shown: Vec<&String> = constant.iter().take(5).collect();
        format!(
            "{} constant across the dataset (zero variance: nothing to learn from, nothing to normalise by)",
            shown
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
                + if constant.len() > 5 { ", ..." } else { "" }
        )
    };
    lint.note(false, message);
}

fn outliers(lint: &mut Lint<'_>, feature: &super::series::LintFeature, episodes: &[EpisodeSeries]) {
    for d in 0..feature.dims {
        let Some((mean, std, _)) = mean_std(dimension(episodes, &feature.name, d)) else {
            continue;
        };
        if std == 0.0 {
            continue;
        }
        let mut count = 0usize;
        let mut first: Option<(u64, usize, f64)> = None;
        for episode in episodes {
            let Some(series) = episode.features.get(&feature.name).filter(|s| d < s.dims) else {
                continue;
            };
            for (t, v) in series.column(d).enumerate() {
                let v = f64::from(v);
                if v.is_finite() && ((v - mean) / std).abs() > OUTLIER_SIGMAS {
                    count += 1;
                    first.get_or_insert((episode.episode, t, v));
                }
            }
        }
        if let Some((episode, t, v)) = first {
            lint.flag(
                episode,
                Some(t as u64),
                format!(
                    "{} is {v}, {:.0} standard deviations from its mean {mean:.4} ({count} such value{} in the dataset)",
                    feature.label(d),
                    ((v - mean) / std).abs(),
                    plural(count)
                ),
            );
        }
    }
}

/// Per task with at least ten episodes, the mean of its last quarter of episodes against its
/// first quarter's, per action and state dimension.
fn drift(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let mut by_task: BTreeMap<Option<i64>, Vec<&EpisodeSeries>> = BTreeMap::new();
    for episode in episodes {
        by_task.entry(episode.task).or_default().push(episode);
    }
    for (task, members) in by_task {
        let n = members.len();
        if n < 10 {
            continue;
        }
        let (first, last) = (&members[..n / 4], &members[n - n / 4..]);
        for feature in dataset.features.iter().filter(|f| is_learned(&f.name)) {
            let values = |group: &[&EpisodeSeries], d: usize| {
                let name = feature.name.clone();
                let group: Vec<&EpisodeSeries> = group.to_vec();
                mean_std(
                    group
                        .into_iter()
                        .filter_map(move |e| e.features.get(&name))
                        .filter(move |s| d < s.dims)
                        .flat_map(move |s| s.column(d).map(f64::from).collect::<Vec<_>>()),
                )
            };
            let worst = (0..feature.dims)
                .filter_map(|d| {
                    let (first_mean, first_std, _) = values(first, d)?;
                    let (last_mean, _, _) = values(last, d)?;
                    let scale = first_std.max(SCALE_FLOOR);
                    Some((d, (last_mean - first_mean).abs() / scale))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((d, shift)) = worst.filter(|w| w.1 > DRIFT_SIGMAS) {
                let task = task.map_or("?".to_string(), |t| t.to_string());
                lint.note(
                    false,
                    format!(
                        "task {task}: {} of its last {} episodes lies {shift:.1} standard deviations from its first {}'s: the setup or the operator drifted?",
                        feature.label(d),
                        n / 4,
                        n / 4
                    ),
                );
            }
        }
    }
}

/// Episodes whose first and last ten actions (their first 20 values) and length agree.
fn duplicates(lint: &mut Lint<'_>, episodes: &[EpisodeSeries]) {
    let mut seen: BTreeMap<Vec<i64>, u64> = BTreeMap::new();
    for episode in episodes {
        let Some(series) = (episode.features.iter())
            .find(|(name, _)| is_action(name))
            .map(|(_, s)| s)
        else {
            continue;
        };
        let frames = series.frames();
        if frames == 0 {
            continue;
        }
        let n = frames.min(10);
        let quantise = |v: &f32| (f64::from(*v) / DUPLICATE_TOLERANCE).round() as i64;
        let mut key: Vec<i64> = series.values[..n * series.dims]
            .iter()
            .take(20)
            .map(quantise)
            .collect();
        key.extend(
            series.values[(frames - n) * series.dims..]
                .iter()
                .take(20)
                .map(quantise),
        );
        key.push(frames as i64);
        if let Some(earlier) = seen.get(&key) {
            lint.flag(
                episode.episode,
                None,
                format!("its first and last actions and length are those of episode {earlier}: a duplicate?"),
            );
        } else {
            seen.insert(key, episode.episode);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dataset, episodes, fired, run};

    #[test]
    fn clean_series_pass_and_each_planted_defect_fires_its_check() {
        let dataset = dataset();
        let clean = episodes(12, 110);
        let report = run(&dataset, &clean);
        assert!(fired(&report).is_empty(), "{:#?}", report.warnings);
        // Frozen: ten repeats of one action.
        let mut frozen = clean.clone();
        let series = frozen[3].features.get_mut("action").unwrap();
        let row: Vec<f32> = series.row(20).to_vec();
        for t in 21..31 {
            series.values[t * 7..t * 7 + 7].copy_from_slice(&row);
        }
        assert_eq!(fired(&run(&dataset, &frozen)), ["frozen-action"]);
        // A jump.
        let mut jumped = clean.clone();
        for d in 0..6 {
            jumped[5].features.get_mut("action").unwrap().values[40 * 7 + d] += 0.5;
        }
        let report = run(&dataset, &jumped);
        assert!(
            fired(&report).contains(&"action-jump".to_string()),
            "{report:#?}"
        );
        let jump = report
            .warnings
            .iter()
            .find(|f| f.check == "action-jump")
            .unwrap();
        assert_eq!((jump.episode, jump.frame), (Some(5), Some(40)));
        // A duplicate.
        let mut duplicated = clean.clone();
        duplicated[7].features = duplicated[2].features.clone();
        let report = run(&dataset, &duplicated);
        assert!(fired(&report).contains(&"duplicate-episodes".to_string()));
    }

    #[test]
    fn a_constant_dimension_and_clipped_values_are_named() {
        let dataset = dataset();
        let mut clean = episodes(12, 110);
        for episode in &mut clean {
            let series = episode.features.get_mut("action").unwrap();
            for t in 0..110 {
                series.values[t * 7 + 4] = 0.0;
                let v = &mut series.values[t * 7];
                *v = v.max(0.0003);
            }
        }
        let report = run(&dataset, &clean);
        let names = fired(&report);
        assert!(names.contains(&"constant".to_string()), "{names:?}");
        assert!(names.contains(&"clipping".to_string()), "{names:?}");
        assert!(
            report
                .warnings
                .iter()
                .any(|f| f.message.contains("action[4] (dpitch_rad) = 0"))
        );
    }
}
