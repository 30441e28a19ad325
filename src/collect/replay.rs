//! `validate --replay`: the check no other dataset validator can make. Every episode of a
//! dataset surgvla collected is re-simulated from its recorded provenance (task id and seed)
//! with the collection's options, its recorded actions replayed and rendered as `collect`
//! renders them; the replay must reach success and reproduce the recorded frames (state and
//! object poses exactly, images pixel for pixel, depth to the format's precision).

use crate::episode::Episode;
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::convert::DEPTH_TOLERANCE_M;
use crate::export::pipeline::{Episodes, in_order};
use crate::export::validate::Finding;
use crate::export::{ExportError, open_source};
use crate::task::success::RULE_SET;
use crate::task::{InstructionChoice, TaskConfig, TaskId};
use rayon::prelude::*;
use std::path::Path;

use super::record::{RecordOptions, render_replay};

/// Why a replay could not start (exit 2).
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("cannot replay {path}: {problem}")]
    NotReplayable {
        path: std::path::PathBuf,
        problem: String,
    },
    #[error(transparent)]
    Export(#[from] ExportError),
}

impl crate::error::HasKind for ReplayError {
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            ReplayError::NotReplayable { .. } => crate::error::ErrorKind::Usage,
            ReplayError::Export(error) => error.kind(),
        }
    }
}

/// The recording options a collection's metadata describes.
fn record_options(collection: &Collection) -> RecordOptions {
    let instruction = match collection.instructions() {
        Some("paraphrase") => InstructionChoice::Paraphrase,
        Some("mixed") => InstructionChoice::Mixed,
        _ => InstructionChoice::Canonical,
    };
    RecordOptions {
        randomize_appearance: collection.randomize_appearance(),
        gripper: collection.gripper_encoding().unwrap_or_default(),
        task: TaskConfig {
            distractors: collection.distractors().unwrap_or(1),
            instruction,
            spawn_scale: collection.spawn_scale().unwrap_or(1.0),
            ..TaskConfig::default()
        },
        ..RecordOptions::default()
    }
}

/// What of a recorded step differs from its replay, if anything (RGB compared within
/// `min_psnr_db` when lossy).
fn step_difference(
    a: &crate::episode::Step,
    b: &crate::episode::Step,
    min_psnr_db: Option<f64>,
) -> Option<&'static str> {
    if a.state != b.state {
        Some("the robot state")
    } else if a.environment_state.iter().any(|v| *v != 0.0)
        && a.environment_state != b.environment_state
    {
        Some("the object poses")
    } else if !a.rgb.is_empty() && crate::export::convert::rgb_differs(&a.rgb, &b.rgb, min_psnr_db)
    {
        Some("the RGB image")
    } else if !a.mask.is_empty() && a.mask != b.mask {
        Some("the mask")
    } else if !a.depth_m.is_empty()
        && a.depth_m
            .iter()
            .zip(&b.depth_m)
            .any(|(x, y)| (x - y).abs() > DEPTH_TOLERANCE_M)
    {
        Some("the depth")
    } else {
        None
    }
}

/// What is wrong with one recorded episode's replay, if anything: (frame, check, message).
/// `judge`: whether the replay must also succeed (the dataset was judged by today's rules).
fn replay_episode(
    recorded: &Episode,
    options: &RecordOptions,
    lossy: bool,
    judge: bool,
) -> Option<(Option<u64>, Check, String)> {
    let meta = &recorded.meta;
    let Ok(task) = meta.task_code.parse::<TaskId>() else {
        return Some((
            None,
            Check::Provenance,
            format!("task id {:?} is not a surgvla task", meta.task_code),
        ));
    };
    let instance = match task.instance(meta.seed, &options.task) {
        Ok(instance) => instance,
        Err(error) => {
            return Some((
                None,
                Check::Replay,
                format!("seed {} does not spawn: {error}", meta.seed),
            ));
        }
    };
    let actions: Vec<[f32; 7]> = recorded.steps.iter().map(|s| s.action).collect();
    let replayed = render_replay(&instance, &actions, meta.index, meta.attempts, options);
    if instance.instruction != meta.instruction {
        return Some((
            None,
            Check::Replay,
            format!(
                "the instruction is {:?}; seed {} gives {:?}",
                meta.instruction, meta.seed, instance.instruction
            ),
        ));
    }
    // Lossy RGB (JPEG, or decoded video) is compared within the lossy tolerance.
    let lossy = lossy
        || recorded
            .encoded
            .iter()
            .any(|e| e.encoding == crate::episode::ImageEncoding::Jpeg);
    let min_psnr_db = lossy.then_some(crate::export::convert::LOSSY_RGB_MIN_PSNR_DB);
    for (frame, (a, b)) in recorded
        .steps
        .iter()
        .zip(&replayed.episode.steps)
        .enumerate()
    {
        let differs = step_difference(a, b, min_psnr_db);
        if let Some(what) = differs {
            return Some((
                Some(frame as u64),
                Check::Replay,
                format!(
                    "{what} differs from the replay of task {} seed {}",
                    meta.task_code, meta.seed
                ),
            ));
        }
    }
    if judge && !replayed.verdict.success {
        return Some((
            None,
            Check::Replay,
            format!(
                "the recorded actions do not succeed when replayed ({})",
                replayed.verdict.reason
            ),
        ));
    }
    None
}

/// What a replay found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Replayed {
    pub errors: Vec<Finding>,
    /// E.g. that success was not judged: the dataset records other success rules.
    pub warnings: Vec<Finding>,
}

/// The warning for a dataset recorded under other success rules than [`RULE_SET`].
fn other_rules(collection: &Collection) -> Finding {
    Finding {
        file: None,
        episode: None,
        frame: None,
        check: Check::Replay,
        message: format!(
            "the dataset records success rules {} where surgvla now judges by {RULE_SET}: frames and states were replayed, success was not judged",
            collection
                .success_rules()
                .unwrap_or("from before they were named")
        ),
    }
}

/// Replays every episode of the dataset at `path` (LeRobot, or RLDS; video decoded, lossy RGB
/// compared within [`crate::export::convert::LOSSY_RGB_MIN_PSNR_DB`]) on `threads` worker
/// threads (0: one per core) and returns what failed. Success is judged only for datasets that
/// record today's success rules ([`RULE_SET`]); older ones have their frames and states checked,
/// with a warning.
pub fn replay_dataset(path: &Path, threads: usize) -> Result<Replayed, ReplayError> {
    let mut source = open_source(path)?;
    // Video is decoded and compared within the lossy tolerance.
    let lossy = crate::export::decoded::Decoded::needed(source.info());
    if lossy {
        source = Box::new(crate::export::decoded::Decoded::new(source)?);
    }
    let Some(collection) = source.info().collection.clone() else {
        return Err(ReplayError::NotReplayable {
            path: path.to_path_buf(),
            problem:
                "it has no surgvla collection metadata (its episodes carry no seeds to re-run)"
                    .into(),
        });
    };
    let options = record_options(&collection);
    let judge = collection.success_rules() == Some(RULE_SET);
    let warnings: Vec<Finding> = (!judge)
        .then(|| other_rules(&collection))
        .into_iter()
        .collect();
    let pool = crate::threads::pool(threads).map_err(ExportError::from)?;
    let mut findings = Vec::new();
    let mut replay = |batch: Vec<Episode>| {
        let problems: Vec<_> = batch
            .par_iter()
            .map(|episode| {
                let problem = replay_episode(episode, &options, lossy, judge);
                (episode.meta.index, problem)
            })
            .collect();
        for (episode, problem) in problems {
            if let Some((frame, check, message)) = problem {
                findings.push(Finding {
                    file: None,
                    episode: Some(episode),
                    frame,
                    check,
                    message,
                });
            }
        }
        Ok(())
    };
    let mut episodes = Episodes::of(vec![&mut *source]);
    let read = pool.install(|| in_order(&mut episodes, |e| e, &mut replay, &mut |_| {}));
    if let Err(error) = read {
        findings.push(Finding {
            file: None,
            episode: None,
            frame: None,
            check: Check::Replay,
            message: format!("reading stopped: {error}"),
        });
    }
    Ok(Replayed {
        errors: findings,
        warnings,
    })
}
