//! Episodes as a trainer uses them: lengths (too short to learn from, outliers, shorter than
//! the action chunks policies predict: ACT's 100, pi0's 50, diffusion's 16), the balance of
//! tasks, instructions that name different tasks alike, splits that share initial states, and
//! what lerobot-train needs (an action feature).

use super::series::{EpisodeSeries, Lint, LintDataset, mean_std};
use crate::export::check::Check;
use std::collections::BTreeMap;

/// Episodes shorter than this many seconds (and five frames) are short (doctor's rule).
pub const SHORT_SECS: f64 = 1.0;
/// An episode this many standard deviations from the mean length is an outlier (doctor: 3).
pub const LENGTH_SIGMAS: f64 = 3.0;
/// Action chunks of the policies users train: (policy, frames).
pub const CHUNKS: [(&str, usize); 3] = [("ACT", 100), ("pi0", 50), ("diffusion policy", 16)];
/// The most common task may have this many times the episodes of the least (doctor: 10).
pub const TASK_IMBALANCE: f64 = 10.0;

pub(super) fn check(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    lengths(lint, dataset, episodes);
    lint.done(
        Check::EpisodeLength,
        false,
        "no episode is under a second long or an outlier in length",
    );
    chunks(lint, episodes);
    lint.done(
        Check::ChunkLength,
        false,
        "every episode is as long as ACT's 100-frame action chunk",
    );
    balance(lint, episodes);
    lint.done(
        Check::TaskBalance,
        false,
        "no task has ten times the episodes of another",
    );
    instructions(lint, dataset, episodes);
    lint.done(
        Check::SameInstruction,
        false,
        "every task's instruction is its own",
    );
    splits(lint, dataset, episodes);
    lint.done(
        Check::SplitOverlap,
        false,
        "no two splits share an initial state",
    );
    training(lint, dataset);
    lint.done(
        Check::Training,
        false,
        "an action feature of a usual size for lerobot-train",
    );
}

fn lengths(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let fps = dataset.fps.unwrap_or(1.0);
    let short = (SHORT_SECS * fps).ceil().max(5.0) as usize;
    let single: Vec<u64> = (episodes.iter())
        .filter(|e| e.frames() <= 1)
        .map(|e| e.episode)
        .collect();
    if !single.is_empty() {
        lint.note(
            true,
            format!(
                "{} episode(s) of one frame or none (no step to learn, no statistics): {}",
                single.len(),
                list(&single)
            ),
        );
    }
    for episode in episodes.iter().filter(|e| (2..short).contains(&e.frames())) {
        lint.flag(
            episode.episode,
            None,
            format!(
                "{} frames: shorter than {short} frames ({SHORT_SECS} s at {fps} fps)",
                episode.frames()
            ),
        );
    }
    // Within each task: tasks differ in length by design.
    let mut by_task: BTreeMap<Option<i64>, Vec<&EpisodeSeries>> = BTreeMap::new();
    for episode in episodes {
        by_task.entry(episode.task).or_default().push(episode);
    }
    for (task, members) in by_task {
        let Some((mean, std, _)) = mean_std(members.iter().map(|e| e.frames() as f64)) else {
            continue;
        };
        let task = task.map_or("?".to_string(), |t| t.to_string());
        if mean > 0.0 && std / mean > 1.0 {
            lint.note(
                false,
                format!(
                    "task {task}'s episode lengths vary widely: standard deviation {std:.0} frames against a mean of {mean:.0}"
                ),
            );
        }
        for episode in members {
            let frames = episode.frames() as f64;
            if std > 0.0 && (frames - mean).abs() > LENGTH_SIGMAS * std {
                lint.flag(
                    episode.episode,
                    None,
                    format!(
                        "{frames} frames: an outlier among task {task}'s episodes ({:.1} standard deviations from their mean {mean:.0})",
                        (frames - mean).abs() / std
                    ),
                );
            }
        }
    }
}

/// One finding for the dataset: how many episodes are shorter than each policy's chunk.
fn chunks(lint: &mut Lint<'_>, episodes: &[EpisodeSeries]) {
    let counts: Vec<String> = CHUNKS
        .iter()
        .filter_map(|(policy, frames)| {
            let shorter = episodes.iter().filter(|e| e.frames() < *frames).count();
            (shorter > 0).then(|| {
                format!(
                    "{shorter} of {} shorter than {policy}'s {frames}-frame chunk",
                    episodes.len()
                )
            })
        })
        .collect();
    if !counts.is_empty() {
        lint.note(
            false,
            format!(
                "episodes: {} (a policy pads past the end: set its chunk size to the episodes)",
                counts.join("; ")
            ),
        );
    }
}

fn balance(lint: &mut Lint<'_>, episodes: &[EpisodeSeries]) {
    let mut counts: BTreeMap<i64, usize> = BTreeMap::new();
    for task in episodes.iter().filter_map(|e| e.task) {
        *counts.entry(task).or_default() += 1;
    }
    let most = counts.iter().max_by_key(|(_, c)| **c);
    let least = counts.iter().min_by_key(|(_, c)| **c);
    if let (Some((most_task, most)), Some((least_task, least))) = (most, least)
        && *most as f64 > TASK_IMBALANCE * *least as f64
    {
        lint.note(
            false,
            format!(
                "task {most_task} has {most} episodes, task {least_task} {least}: more than {TASK_IMBALANCE}x apart"
            ),
        );
    }
}

/// Different tasks (of the episodes) with the same instruction, ignoring case and spaces.
fn instructions(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    let used: std::collections::BTreeSet<i64> = episodes.iter().filter_map(|e| e.task).collect();
    let mut seen: BTreeMap<String, i64> = BTreeMap::new();
    for task in used {
        let Some(text) = usize::try_from(task)
            .ok()
            .and_then(|t| dataset.instructions.get(t))
        else {
            continue;
        };
        let key = text
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
            .to_lowercase();
        if key.is_empty() {
            continue; // the instruction check's
        }
        if let Some(other) = seen.get(&key) {
            lint.note(
                false,
                format!("tasks {other} and {task} have the same instruction {text:?}: a policy cannot tell them apart"),
            );
        } else {
            seen.insert(key, task);
        }
    }
}

/// Episodes of different splits with the same initial state: the same task and seed where
/// provenance records them, else the same first frame of every state feature.
fn splits(lint: &mut Lint<'_>, dataset: &LintDataset, episodes: &[EpisodeSeries]) {
    if dataset.splits.len() < 2 {
        return;
    }
    let split_of = |episode: u64| {
        (dataset.splits.iter())
            .find(|(_, range)| range.contains(&episode))
            .map(|(name, _)| name.as_str())
    };
    let mut seen: BTreeMap<Vec<u8>, (u64, &str)> = BTreeMap::new();
    for episode in episodes {
        let Some(split) = split_of(episode.episode) else {
            continue;
        };
        let key: Vec<u8> = match dataset.seeds.get(&episode.episode) {
            Some((task, seed)) => format!("{task}/{seed}").into_bytes(),
            None => (episode.features.iter())
                .filter(|(name, _)| name.contains("state"))
                .flat_map(|(_, s)| s.values.iter().take(s.dims))
                .flat_map(|v| v.to_le_bytes())
                .collect(),
        };
        if key.is_empty() {
            continue;
        }
        match seen.get(&key) {
            Some((other, other_split)) if *other_split != split => lint.flag(
                episode.episode,
                None,
                format!(
                    "starts where episode {other} of split {other_split:?} starts (split {split:?})"
                ),
            ),
            Some(_) => {}
            None => {
                seen.insert(key, (episode.episode, split));
            }
        }
    }
}

fn training(lint: &mut Lint<'_>, dataset: &LintDataset) {
    match dataset.feature("action") {
        None => lint.note(
            false,
            "no \"action\" feature: lerobot-train and every policy read one",
        ),
        Some(action) if action.dims > 20 => lint.note(
            false,
            format!("action has {} dimensions: unusually many", action.dims),
        ),
        Some(_) => {}
    }
}

/// Up to ten episode indices.
fn list(episodes: &[u64]) -> String {
    let shown: Vec<String> = episodes.iter().take(10).map(u64::to_string).collect();
    let more = if episodes.len() > 10 { ", ..." } else { "" };
    format!("{}{more}", shown.join(", "))
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dataset, episodes, fired, run};

    #[test]
    fn short_episodes_and_chunks_are_counted_once() {
        let dataset = dataset();
        let mut eps = episodes(12, 110);
        eps[4] = super::super::testing::episode(4, 6, 9);
        let report = run(&dataset, &eps);
        let names = fired(&report);
        assert!(names.contains(&"episode-length".to_string()), "{names:?}");
        let chunk: Vec<_> = report
            .warnings
            .iter()
            .filter(|f| f.check == "chunk-length")
            .collect();
        assert_eq!(chunk.len(), 1, "{chunk:#?}");
        assert!(chunk[0].message.contains("1 of 12 shorter than ACT's 100"));
        assert!(
            chunk[0]
                .message
                .contains("1 of 12 shorter than diffusion policy's 16")
        );
    }

    #[test]
    fn splits_sharing_a_seed_and_tasks_sharing_an_instruction_are_named() {
        let mut dataset = dataset();
        dataset.splits = vec![("train".into(), 0..8), ("test".into(), 8..12)];
        dataset.seeds = (0..12).map(|e| (e, ("T1-1".to_string(), e % 10))).collect();
        dataset.instructions = vec!["Pick up the gauze".into(), "pick up  the gauze".into()];
        let mut eps = episodes(12, 110);
        eps[11].task = Some(1);
        let report = run(&dataset, &eps);
        let overlap: Vec<_> = (report.warnings.iter())
            .filter(|f| f.check == "split-overlap")
            .map(|f| f.episode)
            .collect();
        assert_eq!(overlap, [Some(10), Some(11)]);
        assert!(fired(&report).contains(&"same-instruction".to_string()));
    }
}
