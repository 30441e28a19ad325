//! An evaluation's results: per task the trials, successes, success rate with its Wilson 95 %
//! score interval and the mean steps of successful trials; every trial with its seed (which
//! reproduces it) and, for failures, the reason. Written as `results.json`, `results.csv` and
//! `results.md` (the paper's row: one column per task, then the per-task table).

use super::progress::{FailureClass, TrialProgress, stages};
use crate::task::TaskId;
use indexmap::IndexMap;
use serde::Serialize;
use std::fmt::Write as _;

/// z of a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

/// Wilson's score interval for `successes` of `trials` at 95 %: (low, high), (0, 1) when there
/// are no trials. Unlike the normal approximation it stays inside [0, 1] and is not empty at
/// 0 % or 100 %.
pub fn wilson_interval(successes: u32, trials: u32) -> (f64, f64) {
    if trials == 0 {
        return (0.0, 1.0);
    }
    let n = f64::from(trials);
    let p = f64::from(successes) / n;
    let z2 = Z95 * Z95;
    let denominator = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denominator;
    let half = Z95 * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / denominator;
    // Exact bounds at 0 % and 100 % (the formula leaves rounding residue there).
    let low = if successes == 0 {
        0.0
    } else {
        (centre - half).max(0.0)
    };
    let high = if successes == trials {
        1.0
    } else {
        (centre + half).min(1.0)
    };
    (low, high)
}

/// One trial.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TrialResult {
    pub task_id: String,
    /// The perturbation variant the trial ran under ("none": unperturbed).
    pub variant: String,
    /// What the variant drew for this trial, each number named with its unit (empty: none).
    pub perturbation: std::collections::BTreeMap<String, serde_json::Value>,
    /// 0-based trial number within the task.
    pub trial: u32,
    /// The scene seed: `surgvla eval --policy ... --tasks T --trials ...` draws the same scene,
    /// and so does `Env::reset(task, seed, ...)`.
    pub seed: u64,
    pub instruction: String,
    pub success: bool,
    /// Control steps executed.
    pub steps: u32,
    /// Why the trial failed (the predicate's reason, the step limit, or the policy's error);
    /// empty on success.
    pub reason: String,
    /// The policy failed to answer (time-out, malformed reply, closed connection).
    pub policy_error: bool,
    /// Steps whose action had to be clipped to the action space (at most 1 cm per axis, no roll
    /// or pitch, 30 deg of yaw) or to the workspace.
    pub clipped_steps: u32,
    /// The deepest the tool tip went below a kidney's or spleen's surface during the trial,
    /// millimetres (0: never inside one; an honest touch stays within 1 mm).
    pub peak_penetration_mm: f64,
    /// The trial's contact events in time order: grasps and releases of objects, the tip's
    /// entries into the vessel (from above or through its wall), the jaws' closings in it.
    pub events: Vec<TrialEvent>,
    /// The replay baseline's training episode.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replayed_episode: Option<u64>,
    /// The MCAP recording of a failed trial, relative to the results folder.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recording: Option<String>,
    /// The furthest stage, progress, failure class and precision figures
    /// ([`super::progress`]).
    #[serde(flatten)]
    pub progress: TrialProgress,
}

/// One contact event of a trial (`sim::history::ContactEvent`, named).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TrialEvent {
    /// The control step it happened at (0: before the first).
    pub step: u64,
    /// `grasped`, `released`, `entered_vessel_from_above`, `entered_vessel_through_wall`,
    /// `closed_in_vessel`.
    #[serde(deserialize_with = "known_event")]
    pub event: crate::eval::progress::Name,
    /// The object grasped or released.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub object: Option<String>,
}

/// An event's name as read back (a resumed evaluation's journal).
fn known_event<'de, D: serde::Deserializer<'de>>(d: D) -> Result<&'static str, D::Error> {
    let name = <std::borrow::Cow<'de, str> as serde::Deserialize>::deserialize(d)?;
    (crate::sim::history::ContactKind::ALL.into_iter())
        .map(crate::sim::history::ContactKind::name)
        .find(|n| *n == name)
        .ok_or_else(|| serde::de::Error::custom(format!("no event is named {name:?}")))
}

/// One task's row.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TaskResult {
    pub task_id: String,
    /// The perturbation variant ("none": unperturbed).
    pub variant: String,
    /// The unperturbed success rate minus this variant's (same task, same seeds), -1..1; None
    /// for the unperturbed row or when the run has none.
    pub success_drop: Option<f64>,
    pub name: String,
    pub level: u8,
    pub step_limit: u32,
    pub trials: u32,
    pub successes: u32,
    /// successes / trials, 0..1.
    pub success_rate: f64,
    pub ci95_low: f64,
    pub ci95_high: f64,
    /// Mean control steps of the successful trials (None without one).
    pub mean_steps_success: Option<f64>,
    /// Trials that failed because the policy did not answer properly.
    pub policy_errors: u32,
    /// Mean of the trials' progress, 0..1.
    pub mean_progress: f64,
    /// The survival cascade: each stage of the task with the trials that reached it.
    pub stages: IndexMap<&'static str, u32>,
    /// Failed trials by failure class (every class listed).
    pub failure_classes: IndexMap<&'static str, u32>,
    /// Means over the trials that have the figure (None: none has it).
    pub mean_grasp_offset_mm: Option<f64>,
    pub mean_placement_error_mm: Option<f64>,
    pub mean_path_length_mm: f64,
    pub mean_time_to_success_s: Option<f64>,
    pub mean_clip_angle_error_deg: Option<f64>,
    pub mean_covered_fraction_pct: Option<f64>,
    /// Mean tissue contacts away from the target per trial.
    pub mean_tissue_contacts_off_target: f64,
}

/// The mean of the values present, to the micrometre (None without one).
fn mean_of(values: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let present: Vec<f64> = values.flatten().collect();
    (!present.is_empty()).then(|| {
        let mean = present.iter().sum::<f64>() / present.len() as f64;
        (mean * 1e3).round() / 1e3
    })
}

impl TaskResult {
    /// The row of `task` from its trials.
    pub fn of(task: TaskId, trials: &[TrialResult]) -> TaskResult {
        let n = trials.len() as u32;
        let successful: Vec<&TrialResult> = trials.iter().filter(|t| t.success).collect();
        let successes = successful.len() as u32;
        let (ci95_low, ci95_high) = wilson_interval(successes, n);
        TaskResult {
            task_id: task.code().into(),
            variant: "none".into(),
            success_drop: None,
            name: task.name().into(),
            level: task.level(),
            step_limit: task.step_limit(),
            trials: n,
            successes,
            success_rate: if n == 0 {
                0.0
            } else {
                f64::from(successes) / f64::from(n)
            },
            ci95_low,
            ci95_high,
            mean_steps_success: (!successful.is_empty()).then(|| {
                successful.iter().map(|t| f64::from(t.steps)).sum::<f64>() / successful.len() as f64
            }),
            policy_errors: trials.iter().filter(|t| t.policy_error).count() as u32,
            mean_progress: mean_of(trials.iter().map(|t| Some(t.progress.progress))).unwrap_or(0.0),
            stages: stage_counts(task, trials),
            failure_classes: FailureClass::ALL
                .iter()
                .map(|&class| {
                    let count = (trials.iter())
                        .filter(|t| t.progress.failure_class == Some(class))
                        .count();
                    (class.name(), count as u32)
                })
                .collect(),
            mean_grasp_offset_mm: mean_of(trials.iter().map(|t| t.progress.grasp_offset_mm)),
            mean_placement_error_mm: mean_of(trials.iter().map(|t| t.progress.placement_error_mm)),
            mean_path_length_mm: mean_of(trials.iter().map(|t| Some(t.progress.path_length_mm)))
                .unwrap_or(0.0),
            mean_time_to_success_s: mean_of(trials.iter().map(|t| t.progress.time_to_success_s)),
            mean_clip_angle_error_deg: mean_of(
                trials.iter().map(|t| t.progress.clip_angle_error_deg),
            ),
            mean_covered_fraction_pct: mean_of(
                trials.iter().map(|t| t.progress.covered_fraction_pct),
            ),
            mean_tissue_contacts_off_target: mean_of(
                (trials.iter()).map(|t| Some(f64::from(t.progress.tissue_contacts_off_target))),
            )
            .unwrap_or(0.0),
        }
    }
}

/// A change in points with its sign, "±0" when it rounds to zero.
fn change(points: f64, decimals: usize) -> String {
    let text = format!("{points:+.decimals$}");
    if text[1..].chars().all(|c| c == '0' || c == '.') {
        format!("±{}", &text[1..])
    } else {
        text
    }
}

/// Sets each perturbed row's drop from the unperturbed row of its task.
pub fn set_drops(rows: &mut [TaskResult]) {
    let baseline: Vec<(String, f64)> = (rows.iter())
        .filter(|r| r.variant == "none")
        .map(|r| (r.task_id.clone(), r.success_rate))
        .collect();
    for row in rows.iter_mut().filter(|r| r.variant != "none") {
        row.success_drop = (baseline.iter())
            .find(|(task, _)| *task == row.task_id)
            .map(|(_, rate)| ((rate - row.success_rate) * 1e6).round() / 1e6);
    }
}

/// Each stage of `task` with the trials that reached it.
fn stage_counts(task: TaskId, trials: &[TrialResult]) -> IndexMap<&'static str, u32> {
    let chain = stages(task);
    (chain.iter().enumerate())
        .map(|(i, &stage)| {
            let reached = (trials.iter())
                .filter(|t| (t.progress.progress * chain.len() as f64).round() as usize > i)
                .count();
            (stage, reached as u32)
        })
        .collect()
}

/// The whole evaluation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvalReport {
    /// [`RESULTS_SCHEMA`]: the version of `schemas/eval_results.schema.json` the file follows.
    pub results_schema: &'static str,
    /// The policy's name: `--name`, else a served policy's own from its metadata, else its URL;
    /// "expert", "random", "noop" or "replay" for the built-in ones. (The options keep the URL.)
    pub policy: String,
    /// The server's metadata message (remote policies), arrays summarised.
    pub policy_metadata: serde_json::Value,
    /// The options the trials ran with (what the policy was sent, spawn ranges, seeds).
    pub options: serde_json::Value,
    /// One row per task, per variant when perturbed (variants in run order).
    pub tasks: Vec<TaskResult>,
    /// All tasks pooled (the unperturbed rows when the run has them).
    pub overall: TaskTotals,
    pub trials: Vec<TrialResult>,
    pub generator: String,
    /// The success rules the trials were judged by.
    pub success_rules: String,
    /// The perturbation suite the trials ran under: its name, dimensions file, the files'
    /// CRC-32 and its variants in order (absent: unperturbed trials only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub suite: Option<serde_json::Value>,
    /// Trials an interrupted run had scored, which `--resume` took from its journal (never in
    /// the results: a resumed run's equal an uninterrupted one's).
    #[serde(skip)]
    pub resumed_trials: usize,
}

/// The version of results.json's layout (`schemas/eval_results.schema.json`).
pub const RESULTS_SCHEMA: &str = "surgvla-eval-results-v2";

/// results.json's JSON Schema.
pub const RESULTS_JSON_SCHEMA: &str = include_str!("../../schemas/eval_results.schema.json");

/// Trials of all tasks pooled.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TaskTotals {
    pub trials: u32,
    pub successes: u32,
    /// Mean of the per-task success rates (the paper's average column).
    pub mean_success_rate: f64,
}

impl EvalReport {
    pub fn new(
        policy: String,
        policy_metadata: serde_json::Value,
        options: serde_json::Value,
        tasks: Vec<TaskResult>,
        trials: Vec<TrialResult>,
    ) -> EvalReport {
        // A perturbed run's totals are its unperturbed rows' (all rows without one).
        let unperturbed: Vec<&TaskResult> = tasks.iter().filter(|t| t.variant == "none").collect();
        let pooled: Vec<&TaskResult> = if unperturbed.is_empty() {
            tasks.iter().collect()
        } else {
            unperturbed
        };
        let overall = TaskTotals {
            trials: pooled.iter().map(|t| t.trials).sum(),
            successes: pooled.iter().map(|t| t.successes).sum(),
            mean_success_rate: if pooled.is_empty() {
                0.0
            } else {
                pooled.iter().map(|t| t.success_rate).sum::<f64>() / pooled.len() as f64
            },
        };
        EvalReport {
            results_schema: RESULTS_SCHEMA,
            policy,
            policy_metadata,
            options,
            tasks,
            overall,
            trials,
            generator: format!("surgvla {}", env!("CARGO_PKG_VERSION")),
            success_rules: crate::task::success::RULE_SET.into(),
            suite: None,
            resumed_trials: 0,
        }
    }

    /// `results.json`.
    pub fn json(&self) -> String {
        let mut text = serde_json::to_string_pretty(self).unwrap_or_default();
        text.push('\n');
        text
    }

    /// `results.csv`: one row per task.
    pub fn csv(&self) -> String {
        let classes: Vec<&str> = FailureClass::ALL.iter().map(|c| c.name()).collect();
        let mut text = format!(
            "task_id,name,level,trials,successes,success_rate,ci95_low,ci95_high,mean_steps_success,policy_errors,mean_progress,{},mean_grasp_offset_mm,mean_placement_error_mm,mean_path_length_mm,mean_time_to_success_s,mean_clip_angle_error_deg,mean_covered_fraction_pct,mean_tissue_contacts_off_target\n",
            classes.join(",")
        );
        let or_empty = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
        for t in &self.tasks {
            let steps = t
                .mean_steps_success
                .map(|s| format!("{s:.1}"))
                .unwrap_or_default();
            let counts: Vec<String> = (t.failure_classes.values()).map(u32::to_string).collect();
            let _ = writeln!(
                text,
                "{},{},{},{},{},{:.4},{:.4},{:.4},{},{},{:.4},{},{},{},{},{},{},{},{}",
                t.task_id,
                t.name,
                t.level,
                t.trials,
                t.successes,
                t.success_rate,
                t.ci95_low,
                t.ci95_high,
                steps,
                t.policy_errors,
                t.mean_progress,
                counts.join(","),
                or_empty(t.mean_grasp_offset_mm),
                or_empty(t.mean_placement_error_mm),
                t.mean_path_length_mm,
                or_empty(t.mean_time_to_success_s),
                or_empty(t.mean_clip_angle_error_deg),
                or_empty(t.mean_covered_fraction_pct),
                t.mean_tissue_contacts_off_target,
            );
        }
        text
    }

    /// The survival cascade and failure classes per task, as Markdown lines.
    pub fn stages_markdown(&self) -> String {
        let mut text = String::from(
            "Stages reached (of the trials), mean progress, and failures by class:\n\n",
        );
        for t in &self.tasks {
            let cascade: Vec<String> = (t.stages.iter())
                .map(|(stage, n)| format!("{stage} {n}"))
                .collect();
            let failures: Vec<String> = (t.failure_classes.iter())
                .filter(|(_, n)| **n > 0)
                .map(|(class, n)| format!("{class} {n}"))
                .collect();
            let failures = if failures.is_empty() {
                "none".to_string()
            } else {
                failures.join(", ")
            };
            let _ = writeln!(
                text,
                "- {} ({} trials): {}; progress {:.2}; failures: {}",
                self.label(t),
                t.trials,
                cascade.join(" -> "),
                t.mean_progress,
                failures
            );
        }
        text
    }

    /// Whether the rows are of several variants or of a perturbed one.
    fn perturbed(&self) -> bool {
        self.tasks.iter().any(|t| t.variant != "none")
    }

    /// A task's label: its id, and its variant when the run is perturbed.
    fn label(&self, t: &TaskResult) -> String {
        if self.perturbed() {
            format!("{} [{}]", t.task_id, t.variant)
        } else {
            t.task_id.clone()
        }
    }

    /// The task x variant grid of a perturbed run (None otherwise): each cell the success rate
    /// with its Wilson interval and the drop from the unperturbed run, a mean column last; as
    /// (head, rows).
    fn variants_grid(&self) -> Option<(Vec<String>, Vec<Vec<String>>)> {
        if !self.perturbed() {
            return None;
        }
        let mut variants: Vec<&str> = Vec::new();
        let mut tasks: Vec<&str> = Vec::new();
        for t in &self.tasks {
            if !variants.contains(&t.variant.as_str()) {
                variants.push(&t.variant);
            }
            if !tasks.contains(&t.task_id.as_str()) {
                tasks.push(&t.task_id);
            }
        }
        let mut head = vec!["variant".to_string()];
        head.extend(tasks.iter().map(|t| t.to_string()));
        head.extend(["mean".to_string(), "drop".to_string()]);
        let mut grid = Vec::new();
        for variant in variants {
            let rows: Vec<&TaskResult> = (self.tasks.iter())
                .filter(|t| t.variant == variant)
                .collect();
            let mut cells = vec![variant.to_string()];
            cells.extend(tasks.iter().map(|id| {
                rows.iter().find(|t| t.task_id == *id).map_or_else(
                    || "-".into(),
                    |t| {
                        let drop = t
                            .success_drop
                            .map_or_else(String::new, |d| format!(" ({})", change(-100.0 * d, 0)));
                        format!(
                            "{:.0} [{:.0}-{:.0}]{drop}",
                            100.0 * t.success_rate,
                            100.0 * t.ci95_low,
                            100.0 * t.ci95_high
                        )
                    },
                )
            }));
            let n = rows.len().max(1) as f64;
            let mean = rows.iter().map(|t| t.success_rate).sum::<f64>() / n;
            let drops: Vec<f64> = rows.iter().filter_map(|t| t.success_drop).collect();
            let drop = if drops.is_empty() {
                "-".to_string()
            } else {
                change(-100.0 * drops.iter().sum::<f64>() / drops.len() as f64, 1)
            };
            cells.extend([format!("{:.1}", 100.0 * mean), drop]);
            grid.push(cells);
        }
        Some((head, grid))
    }

    /// The lead-in of the variants grid.
    const GRID_TITLE: &str = "Success rate in % [Wilson 95 % interval] and drop from the unperturbed run, in points, per variant and task:";

    /// [`EvalReport::variants_grid`] as a Markdown table (results.md).
    pub fn variants_markdown(&self) -> Option<String> {
        let (head, rows) = self.variants_grid()?;
        let mut text = format!("{}\n\n", Self::GRID_TITLE);
        let _ = writeln!(
            text,
            "| {} |\n|---|{}---:|---:|",
            head.join(" | "),
            "---|".repeat(head.len() - 3)
        );
        for row in rows {
            let _ = writeln!(text, "| {} |", row.join(" | "));
        }
        Some(text)
    }

    /// [`EvalReport::variants_grid`] in aligned columns, as the terminal shows it.
    pub fn variants_terminal(&self) -> Option<String> {
        let (head, rows) = self.variants_grid()?;
        let head: Vec<&str> = head.iter().map(String::as_str).collect();
        Some(format!(
            "{}\n{}",
            Self::GRID_TITLE,
            aligned(&head, &rows, 1)
        ))
    }

    /// The precision and safety means per task, as a Markdown table ("-" where no trial has the
    /// figure).
    pub fn precision_markdown(&self) -> String {
        let mut text = String::from(
            "Precision and safety, means over the trials that have the figure:\n\n| task | grasp offset (mm) | placement error (mm) | covered (%) | clip angle error (deg) | tissue contacts off target | path (mm) | time to success (s) |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
        );
        let or_dash = |v: Option<f64>, decimals: usize| {
            v.map_or_else(|| "-".to_string(), |v| format!("{v:.decimals$}"))
        };
        for t in &self.tasks {
            let _ = writeln!(
                text,
                "| {} | {} | {} | {} | {} | {:.2} | {:.0} | {} |",
                self.label(t),
                or_dash(t.mean_grasp_offset_mm, 1),
                or_dash(t.mean_placement_error_mm, 1),
                or_dash(t.mean_covered_fraction_pct, 1),
                or_dash(t.mean_clip_angle_error_deg, 1),
                t.mean_tissue_contacts_off_target,
                t.mean_path_length_mm,
                or_dash(t.mean_time_to_success_s, 1),
            );
        }
        text
    }

    /// The per-task table (what the command prints).
    pub fn table(&self) -> String {
        let mut text = String::from(
            "| task | name | trials | successes | success rate | Wilson 95 % CI | mean steps (successes) |\n|---|---|---:|---:|---:|---|---:|\n",
        );
        for t in &self.tasks {
            let steps = t
                .mean_steps_success
                .map_or_else(|| "-".into(), |s| format!("{s:.1}"));
            let _ = writeln!(
                text,
                "| {} | {} | {} | {} | {:.1} % | {:.1} - {:.1} % | {} |",
                self.label(t),
                t.name,
                t.trials,
                t.successes,
                100.0 * t.success_rate,
                100.0 * t.ci95_low,
                100.0 * t.ci95_high,
                steps
            );
        }
        text
    }

    /// The per-task table as the terminal shows it: aligned columns, as `collect` prints its
    /// table (results.md has [`EvalReport::table`], in Markdown).
    pub fn terminal_table(&self) -> String {
        let head = [
            "task",
            "name",
            "trials",
            "successes",
            "rate",
            "95 % CI",
            "mean steps",
        ];
        let rows: Vec<Vec<String>> = (self.tasks.iter())
            .map(|t| {
                vec![
                    self.label(t),
                    t.name.clone(),
                    t.trials.to_string(),
                    t.successes.to_string(),
                    format!("{:.1} %", 100.0 * t.success_rate),
                    format!("{:.1}-{:.1} %", 100.0 * t.ci95_low, 100.0 * t.ci95_high),
                    (t.mean_steps_success).map_or_else(|| "-".into(), |s| format!("{s:.1}")),
                ]
            })
            .collect();
        aligned(&head, &rows, 2)
    }

    /// `results.md`: the paper-style row, the per-task table, the options and the recordings.
    pub fn markdown(&self) -> String {
        let mut text = format!("# surgvla eval: {}\n\n", self.policy);
        if let Some(grid) = self.variants_markdown() {
            text.push_str(&grid);
            text.push('\n');
        } else {
            let heads: Vec<&str> = self.tasks.iter().map(|t| t.task_id.as_str()).collect();
            let _ = writeln!(
                text,
                "| policy | {} | mean |\n|---|{}---:|",
                heads.join(" | "),
                "---:|".repeat(heads.len())
            );
            let rates: Vec<String> = (self.tasks.iter())
                .map(|t| format!("{:.1}", 100.0 * t.success_rate))
                .collect();
            let _ = writeln!(
                text,
                "| {} | {} | {:.1} |\n",
                self.policy,
                rates.join(" | "),
                100.0 * self.overall.mean_success_rate
            );
        }
        text.push_str("Success rates in %.\n\n");
        text.push_str(&self.table());
        text.push('\n');
        text.push_str(&self.stages_markdown());
        text.push('\n');
        text.push_str(&self.precision_markdown());
        let _ = writeln!(
            text,
            "\nOptions: `{}`\n",
            serde_json::to_string(&self.options).unwrap_or_default()
        );
        if !self.policy_metadata.is_null() {
            let _ = writeln!(
                text,
                "Server metadata: `{}`\n",
                serde_json::to_string(&self.policy_metadata).unwrap_or_default()
            );
        }
        let recorded: Vec<&TrialResult> = self
            .trials
            .iter()
            .filter(|t| t.recording.is_some())
            .collect();
        if !recorded.is_empty() {
            text.push_str(
                "Recorded failures (open in Foxglove; the seed reproduces the scene):\n\n",
            );
            for t in recorded {
                let _ = writeln!(
                    text,
                    "- {} trial {} (seed {}): {} -> `{}`",
                    t.task_id,
                    t.trial,
                    t.seed,
                    t.reason,
                    t.recording.as_deref().unwrap_or_default()
                );
            }
        }
        text
    }
}

/// `head` and `rows` as columns padded to their widest cell, one space apart: the first `left`
/// columns flush left (names), the rest flush right (numbers).
pub fn aligned(head: &[&str], rows: &[Vec<String>], left: usize) -> String {
    let cells = |row: &[String]| row.iter().map(|c| c.chars().count()).collect::<Vec<_>>();
    let mut widths: Vec<usize> = head.iter().map(|h| h.chars().count()).collect();
    for row in rows {
        for (w, c) in widths.iter_mut().zip(cells(row)) {
            *w = (*w).max(c);
        }
    }
    let line = |row: &[String]| {
        let padded: Vec<String> = (row.iter().zip(&widths).enumerate())
            .map(|(i, (cell, w))| {
                if i < left {
                    format!("{cell:<w$}")
                } else {
                    format!("{cell:>w$}")
                }
            })
            .collect();
        padded.join(" ").trim_end().to_string()
    };
    let head: Vec<String> = head.iter().map(|h| h.to_string()).collect();
    let mut text = line(&head);
    text.push('\n');
    for row in rows {
        text.push_str(&line(row));
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_published_values() {
        // Reference values (Newcombe 1998, method 3 without continuity correction).
        let (low, high) = wilson_interval(81, 263);
        assert!(
            (low - 0.2553).abs() < 1e-4 && (high - 0.3662).abs() < 1e-4,
            "{low} {high}"
        );
        let (low, high) = wilson_interval(0, 50);
        assert_eq!(low, 0.0);
        assert!((high - 0.0713).abs() < 1e-4, "{high}");
        let (low, high) = wilson_interval(50, 50);
        assert!(
            (low - 0.9287).abs() < 1e-4 && (high - 1.0).abs() < 1e-12,
            "{low}"
        );
        assert_eq!(wilson_interval(0, 0), (0.0, 1.0));
    }

    fn trial(success: bool, steps: u32) -> TrialResult {
        TrialResult {
            variant: "none".into(),
            perturbation: Default::default(),
            task_id: "T1-1".into(),
            trial: 0,
            seed: 1,
            instruction: "pick up the gauze".into(),
            success,
            steps,
            reason: String::new(),
            policy_error: !success,
            clipped_steps: 0,
            peak_penetration_mm: 0.0,
            events: Vec::new(),
            replayed_episode: None,
            recording: None,
            progress: TrialProgress::default(),
        }
    }

    #[test]
    fn a_row_counts_its_trials() {
        let trials = [trial(true, 40), trial(true, 60), trial(false, 100)];
        let row = TaskResult::of(TaskId::GauzePick, &trials);
        assert_eq!((row.trials, row.successes, row.policy_errors), (3, 2, 1));
        assert!((row.success_rate - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(row.mean_steps_success, Some(50.0));
        let report = EvalReport::new(
            "noop".into(),
            serde_json::Value::Null,
            serde_json::json!({}),
            vec![row],
            trials.to_vec(),
        );
        assert!(
            report
                .csv()
                .lines()
                .nth(1)
                .expect("a row")
                .starts_with("T1-1,gauze_pick,1,3,2,0.6667,")
        );
        assert!(report.markdown().contains("| noop | 66.7 | 66.7 |"));
        let json: serde_json::Value = serde_json::from_str(&report.json()).expect("json");
        assert_eq!(json["tasks"][0]["task_id"], "T1-1");
        assert_eq!(json["overall"]["successes"], 2);
    }
}
