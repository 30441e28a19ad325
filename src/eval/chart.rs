//! The success-rate chart of one or several evaluations: each task's rate with its Wilson 95 %
//! interval, policies side by side, tasks grouped by level ([`crate::chart::plots::rate_chart`]).
//! `eval` draws its own run as `results.png`; `surgvla report` reads several runs'
//! `results.json` ([`read_results`]) and draws them together: the paper's table as a chart, or
//! a perturbation suite's run as a task x variant heatmap ([`heatmap_of`]).

use crate::chart::heatmap::{HeatCell, HeatRow, Heatmap, heatmap};
use crate::chart::plots::{Category, Rate, RateChart, rate_chart};
use crate::export::ExportError;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// What the chart needs of a run's `results.json`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct RunRates {
    pub policy: String,
    pub tasks: Vec<TaskRate>,
}

/// One task's rate in a run.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct TaskRate {
    pub task_id: String,
    pub level: u8,
    pub success_rate: f64,
    pub ci95_low: f64,
    pub ci95_high: f64,
    /// The perturbation variant (results before variants: "none").
    #[serde(default = "unperturbed")]
    pub variant: String,
    #[serde(default)]
    pub success_drop: Option<f64>,
    #[serde(default)]
    pub trials: u32,
    #[serde(default)]
    pub successes: u32,
    /// The survival cascade: each stage with the trials that reached it (results before
    /// stages: empty).
    #[serde(default)]
    pub stages: indexmap::IndexMap<String, u32>,
}

fn unperturbed() -> String {
    "none".into()
}

impl RunRates {
    /// Whether the run has perturbed rows.
    pub fn perturbed(&self) -> bool {
        self.tasks.iter().any(|t| t.variant != "none")
    }

    /// The run's variants in run order.
    fn variants(&self) -> Vec<&str> {
        let mut variants: Vec<&str> = Vec::new();
        for t in &self.tasks {
            if !variants.contains(&t.variant.as_str()) {
                variants.push(&t.variant);
            }
        }
        variants
    }
}

/// The task x variant heatmap of `runs` (None when none is perturbed): a row per run and
/// variant (labelled `name: variant` when there are several runs), a column per task by level
/// then id, and a mean column (the row's trials pooled, its drop the mean of the tasks').
pub fn heatmap_of(title: &str, runs: &[RunRates], names: &[String]) -> Option<Heatmap> {
    if !runs.iter().any(RunRates::perturbed) {
        return None;
    }
    let mut tasks: Vec<(u8, String)> = (runs.iter())
        .flat_map(|r| r.tasks.iter().map(|t| (t.level, t.task_id.clone())))
        .collect();
    tasks.sort();
    tasks.dedup();
    let mut rows = Vec::new();
    for (run, name) in runs.iter().zip(names) {
        for variant in run.variants() {
            let of_variant: Vec<&TaskRate> =
                run.tasks.iter().filter(|t| t.variant == variant).collect();
            let mut cells: Vec<Option<HeatCell>> = (tasks.iter())
                .map(|(_, id)| {
                    (of_variant.iter())
                        .find(|t| t.task_id == *id)
                        .map(|t| HeatCell {
                            rate: Rate {
                                value: t.success_rate,
                                low: t.ci95_low,
                                high: t.ci95_high,
                            },
                            drop: t.success_drop,
                        })
                })
                .collect();
            let trials: u32 = of_variant.iter().map(|t| t.trials).sum();
            let successes: u32 = of_variant.iter().map(|t| t.successes).sum();
            let drops: Vec<f64> = of_variant.iter().filter_map(|t| t.success_drop).collect();
            cells.push((trials > 0).then(|| {
                let (low, high) = super::results::wilson_interval(successes, trials);
                HeatCell {
                    rate: Rate {
                        value: f64::from(successes) / f64::from(trials),
                        low,
                        high,
                    },
                    drop: (!drops.is_empty())
                        .then(|| drops.iter().sum::<f64>() / drops.len() as f64),
                }
            }));
            let label = if runs.len() > 1 {
                format!("{name}: {variant}")
            } else {
                variant.to_string()
            };
            rows.push(HeatRow { label, cells });
        }
    }
    let mut columns: Vec<String> = tasks.into_iter().map(|(_, id)| id).collect();
    columns.push("mean".into());
    Some(Heatmap {
        title: title.to_string(),
        columns,
        rows,
    })
}

/// Why a run's results cannot be charted.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{dir} holds no results.json: give the folders `surgvla eval --out` wrote")]
    Missing { dir: PathBuf },
    /// The file names itself.
    #[error(transparent)]
    Read(ExportError),
    #[error("{path} is not an evaluation's results.json: {problem}")]
    NotResults { path: PathBuf, problem: String },
    #[error("writing {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: ExportError,
    },
}

impl crate::error::HasKind for ReportError {
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            ReportError::Read(source) | ReportError::Write { source, .. } => source.kind(),
            ReportError::Missing { .. } => crate::error::ErrorKind::Usage,
            ReportError::NotResults { .. } => crate::error::ErrorKind::Failed,
        }
    }

    fn is_disk_full(&self) -> bool {
        matches!(self, ReportError::Write { source, .. } if source.is_disk_full())
    }
}

/// The rates of the run whose results are in `dir` (its `results.json`), refusing rates outside
/// [0, 1].
pub fn read_results(dir: &Path) -> Result<RunRates, ReportError> {
    let path = dir.join("results.json");
    if !path.is_file() {
        return Err(ReportError::Missing {
            dir: dir.to_path_buf(),
        });
    }
    let bytes = crate::export::bounded::read_metadata(&path).map_err(ReportError::Read)?;
    let rates: RunRates = serde_json::from_slice(&bytes).map_err(|e| ReportError::NotResults {
        path: path.clone(),
        problem: e.to_string(),
    })?;
    for task in &rates.tasks {
        let values = [task.success_rate, task.ci95_low, task.ci95_high];
        if values.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Err(ReportError::NotResults {
                path,
                problem: format!("{} has a rate outside 0..1", task.task_id),
            });
        }
    }
    Ok(rates)
}

/// The chart of `runs` (one series each, named by `names`): every task any run scored, by
/// level then id.
pub fn chart_of(title: &str, runs: &[RunRates], names: &[String]) -> RateChart {
    let mut tasks: Vec<(u8, String)> = runs
        .iter()
        .flat_map(|r| r.tasks.iter().map(|t| (t.level, t.task_id.clone())))
        .collect();
    tasks.sort();
    tasks.dedup();
    let rates = runs
        .iter()
        .map(|run| {
            tasks
                .iter()
                .map(|(_, id)| {
                    (run.tasks.iter())
                        .find(|t| t.task_id == *id && t.variant == "none")
                        .map(|t| Rate {
                            value: t.success_rate,
                            low: t.ci95_low,
                            high: t.ci95_high,
                        })
                })
                .collect()
        })
        .collect();
    RateChart {
        title: title.to_string(),
        series: names.to_vec(),
        categories: tasks
            .iter()
            .map(|(level, id)| Category {
                label: id.clone(),
                group: format!("level {level}"),
            })
            .collect(),
        rates,
    }
}

/// A stage's label under its bar (six characters fit).
fn stage_label(stage: &str) -> &str {
    match stage {
        "reached" => "reach",
        "grasped" => "grasp",
        "lifted" => "lift",
        "touched" => "touch",
        "jaws_around_vessel" => "around",
        "clipped" => "clip",
        "transported" => "carry",
        "released_on_target" => "let go",
        "settled" => "settle",
        other => other,
    }
}

/// The cascade chart's title.
pub const CASCADE_TITLE: &str = "stages reached per task (share of trials, 95 % interval)";

/// The survival cascade of `runs` (their unperturbed rows): per task, each stage's share of
/// the trials that reached it, with its Wilson interval, runs side by side, tasks by level then
/// id (None when no run records stages).
pub fn cascade_of(title: &str, runs: &[RunRates], names: &[String]) -> Option<RateChart> {
    let rows = |run: &RunRates| -> Vec<TaskRate> {
        (run.tasks.iter())
            .filter(|t| t.variant == "none" && !t.stages.is_empty() && t.trials > 0)
            .cloned()
            .collect()
    };
    let mut tasks: Vec<(u8, String, Vec<String>)> = (runs.iter())
        .flat_map(|r| rows(r).into_iter())
        .map(|t| (t.level, t.task_id, t.stages.keys().cloned().collect()))
        .collect();
    tasks.sort();
    tasks.dedup_by(|a, b| a.1 == b.1);
    if tasks.is_empty() {
        return None;
    }
    let categories: Vec<(String, String)> = (tasks.iter())
        .flat_map(|(_, id, stages)| stages.iter().map(move |s| (id.clone(), s.clone())))
        .collect();
    let rates = (runs.iter())
        .map(|run| {
            let rows = rows(run);
            (categories.iter())
                .map(|(id, stage)| {
                    let row = rows.iter().find(|t| t.task_id == *id)?;
                    let reached = *row.stages.get(stage)?;
                    let (low, high) = super::results::wilson_interval(reached, row.trials);
                    Some(Rate {
                        value: f64::from(reached) / f64::from(row.trials),
                        low,
                        high,
                    })
                })
                .collect()
        })
        .collect();
    Some(RateChart {
        title: title.to_string(),
        series: names.to_vec(),
        categories: (categories.iter())
            .map(|(id, stage)| Category {
                label: stage_label(stage).to_string(),
                group: id.clone(),
            })
            .collect(),
        rates,
    })
}

/// What `report` draws: the rate chart, or a suite's heatmap.
pub enum Chart {
    Rates(RateChart),
    Heatmap(Heatmap),
}

impl Chart {
    /// The chart drawn.
    pub fn canvas(&self) -> crate::chart::Canvas {
        match self {
            Chart::Rates(chart) => rate_chart(chart).0,
            Chart::Heatmap(map) => heatmap(map),
        }
    }
}

/// The chart as PNG bytes, written to `path` atomically.
pub fn write_chart(chart: &Chart, path: &Path) -> Result<(), ReportError> {
    let write = |source| ReportError::Write {
        path: path.to_path_buf(),
        source,
    };
    let png = chart.canvas().png().map_err(|e| {
        write(ExportError::Encode {
            what: "the chart's PNG".into(),
            source: Box::new(e),
        })
    })?;
    crate::export::write_atomically(path, &png).map_err(write)?;
    Ok(())
}
