//! What the lint's checks share: an episode's numeric series ([`EpisodeSeries`]), the dataset
//! as the lint sees it ([`LintDataset`]), and [`Lint`], which the checks report into: per
//! episode flags held until a check ends, then reported (once, with the count, when they hit
//! every episode) with the check's one-line summary.

use crate::episode::GripperEncoding;
use crate::export::check::Check;
use crate::export::findings::{At, Findings, LintSummary};
use std::collections::BTreeMap;

/// One numeric feature's values over an episode: `dims` values per frame, frame after frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    pub dims: usize,
    pub values: Vec<f32>,
}

impl Series {
    pub fn frames(&self) -> usize {
        self.values.len() / self.dims.max(1)
    }

    /// Frame `t`'s values.
    pub fn row(&self, t: usize) -> &[f32] {
        &self.values[t * self.dims..(t + 1) * self.dims]
    }

    /// The rows, frame after frame.
    pub fn rows(&self) -> std::slice::ChunksExact<'_, f32> {
        self.values.chunks_exact(self.dims.max(1))
    }

    /// Dimension `d` over the episode.
    pub fn column(&self, d: usize) -> impl Iterator<Item = f32> + '_ {
        self.rows().map(move |row| row[d])
    }
}

/// One episode as the lint sees it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EpisodeSeries {
    pub episode: u64,
    /// The task index of its first frame.
    pub task: Option<i64>,
    pub timestamps_secs: Vec<f64>,
    /// Feature name -> its values.
    pub features: BTreeMap<String, Series>,
}

impl EpisodeSeries {
    pub fn frames(&self) -> usize {
        self.timestamps_secs.len().max(
            self.features
                .values()
                .map(Series::frames)
                .max()
                .unwrap_or(0),
        )
    }
}

/// A numeric feature as declared: its name and, when the metadata gives them, one name per
/// dimension.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LintFeature {
    pub name: String,
    pub dims: usize,
    pub names: Vec<String>,
}

impl LintFeature {
    /// Dimension `d` as a report names it: `action[6] (gripper_open)`.
    pub fn label(&self, d: usize) -> String {
        match self.names.get(d) {
            Some(name) => format!("{}[{d}] ({name})", self.name),
            None => format!("{}[{d}]", self.name),
        }
    }
}

/// What the lint knows of the dataset besides its series.
#[derive(Clone, Debug, Default)]
pub struct LintDataset {
    pub fps: Option<f64>,
    /// The numeric features, as declared.
    pub features: Vec<LintFeature>,
    /// Whether timestamps are stored as float32.
    pub timestamp_f32: bool,
    /// Instructions, by task index.
    pub instructions: Vec<String>,
    /// How our datasets encode the gripper action (None: not ours).
    pub gripper: Option<GripperEncoding>,
    /// Split name -> the episodes it holds (info.json's `splits`).
    pub splits: Vec<(String, std::ops::Range<u64>)>,
    /// Episode -> (task id, seed), where provenance records them.
    pub seeds: BTreeMap<u64, (String, u64)>,
}

impl LintDataset {
    pub fn feature(&self, name: &str) -> Option<&LintFeature> {
        self.features.iter().find(|f| f.name == name)
    }
}

/// A finding of one episode, held until its check ends.
struct Flag {
    episode: u64,
    frame: Option<u64>,
    message: String,
}

/// What the checks report into: per-episode flags held per check until [`Lint::done`], which
/// reports them (once, with the count, when they hit every episode) and the summary line.
pub(crate) struct Lint<'a> {
    findings: &'a Findings,
    /// The file findings name (the data folder).
    file: String,
    episodes: usize,
    flags: Vec<Flag>,
    /// Dataset-level findings of the current check: (is_error, message).
    notes: Vec<(bool, String)>,
}

impl<'a> Lint<'a> {
    pub(crate) fn new(findings: &'a Findings, file: &str, episodes: usize) -> Self {
        Lint {
            findings,
            file: file.to_string(),
            episodes,
            flags: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// A finding about `episode` (at `frame`).
    pub(crate) fn flag(&mut self, episode: u64, frame: Option<u64>, message: impl Into<String>) {
        self.flags.push(Flag {
            episode,
            frame,
            message: message.into(),
        });
    }

    /// A finding about the whole dataset.
    pub(crate) fn note(&mut self, is_error: bool, message: impl Into<String>) {
        self.notes.push((is_error, message.into()));
    }

    /// Ends `check`: its findings reported (errors when `is_error`), its summary line `ok`
    /// when it found nothing.
    pub(crate) fn done(&mut self, check: Check, is_error: bool, ok: &str) {
        let flags = std::mem::take(&mut self.flags);
        let notes = std::mem::take(&mut self.notes);
        let report = |at: At, is_error: bool, message: String| {
            if is_error {
                self.findings.error(at, check, message);
            } else {
                self.findings.warning(at, check, message);
            }
        };
        let flagged: std::collections::BTreeSet<u64> = flags.iter().map(|f| f.episode).collect();
        let every = self.episodes > 1 && flagged.len() == self.episodes;
        let first = flags.first().map(|f| (f.episode, f.message.clone()));
        if every && let Some((episode, message)) = &first {
            report(
                At::file(self.file.clone()),
                is_error,
                format!(
                    "every episode ({}), e.g. episode {episode}: {message}",
                    self.episodes
                ),
            );
        } else {
            for flag in flags {
                let mut at = At::file(self.file.clone()).episode(flag.episode);
                if let Some(frame) = flag.frame {
                    at = at.frame(frame);
                }
                report(at, is_error, flag.message);
            }
        }
        let any_error = notes.iter().any(|(e, _)| *e) || (is_error && !flagged.is_empty());
        let status = match (flagged.is_empty() && notes.is_empty(), any_error) {
            (true, _) => "ok",
            (false, true) => "error",
            (false, false) => "warning",
        };
        // The first episode flagged, else the first note about the dataset, else `ok`.
        let line = match (&first, notes.first()) {
            (Some((episode, message)), _) => format!(
                "{} of {} episodes, e.g. episode {episode}: {message}",
                flagged.len(),
                self.episodes
            ),
            (None, Some((_, note))) => note.clone(),
            (None, None) => ok.to_string(),
        };
        for (is_error, message) in notes {
            report(At::file(self.file.clone()), is_error, message);
        }
        self.findings.summarise(LintSummary {
            check,
            status,
            line,
        });
    }
}

/// The features whose name starts with `action` (lerobot-doctor's action columns).
pub(crate) fn is_action(name: &str) -> bool {
    name.starts_with("action")
}

/// Mean and standard deviation (population) of finite values.
pub(crate) fn mean_std(values: impl Iterator<Item = f64>) -> Option<(f64, f64, usize)> {
    let (mut n, mut sum, mut sum_sq) = (0usize, 0.0f64, 0.0f64);
    for v in values.filter(|v| v.is_finite()) {
        n += 1;
        sum += v;
        sum_sq += v * v;
    }
    if n == 0 {
        return None;
    }
    let mean = sum / n as f64;
    let var = (sum_sq / n as f64 - mean * mean).max(0.0);
    Some((mean, var.sqrt(), n))
}

/// The episodes holding `feature` as declared, each with its series.
pub(crate) fn with_feature<'a>(
    feature: &'a LintFeature,
    episodes: &'a [EpisodeSeries],
) -> impl Iterator<Item = (&'a EpisodeSeries, &'a Series)> + 'a {
    episodes.iter().filter_map(move |e| {
        (e.features.get(&feature.name))
            .filter(|s| s.dims == feature.dims)
            .map(|s| (e, s))
    })
}

/// "s" unless `count` is one.
pub(crate) fn plural(count: usize) -> &'static str {
    if count == 1 { "" } else { "s" }
}
