//! Running the trials: each is an [`Env`] of one task drawn from [`trial_seed`], stepped with
//! the agent's commands until the task succeeds, the step limit is reached, the agent stops or
//! it fails to answer (that trial fails with the reason; the evaluation goes on).
//!
//! The built-in policies run headless and in parallel (their trials are pure functions of the
//! seed, so a failed one is re-run with rendering to record it); a remote policy sees rendered
//! observations and runs one trial at a time over its one connection.

use super::agents::{
    Agent, Command, ExpertAgent, NoopAgent, RandomAgent, RemoteAgent, ReplayLibrary,
};
use super::journal::{JOURNAL, Journal};
use super::numpy::metadata_json;
use super::options::{EvalError, EvalOptions, PolicyChoice};
use super::perturb::{Dimensions, Drawn, Suite, Variant};
use super::progress::ProgressTracker;
use super::remote::RemotePolicy;
use super::results::{EvalReport, TaskResult, TrialEvent, TrialResult};
use crate::env::{Env, EnvObservation, EnvOptions, Images};
use crate::episode::{Episode, EpisodeMeta, FeatureSet, Step};
use crate::export::collection::{Collection, EvaluationRecord};
use crate::export::mcap::{McapOptions, record_episode};
use crate::policy::{ExpertLibrary, RandomPolicy};
use crate::rng::SplitMix64;
use crate::sim::JawCommand;
use crate::sim::history::TrialHistory;
use crate::sim::psm::wrap_angle;
use crate::task::{TaskId, TaskInstance, Verdict};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// The scene seed of trial `trial` of `task`: a stream of its own ("eval/T1-1", ...), so
/// evaluation scenes are drawn independently of the collection's (which use the stream named by
/// the task id alone); `tests` checks that the default evaluation and collection seeds share
/// none.
pub fn trial_seed(seed: u64, task: TaskId, trial: u32) -> u64 {
    let mixed = seed ^ u64::from(trial).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    SplitMix64::stream(mixed, &format!("eval/{}", task.code())).next_u64()
}

/// A policy ready to run.
enum Prepared {
    Remote(Box<RemotePolicy>),
    Builtin(Builtin),
}

/// A built-in policy: its trials are pure functions of their seeds.
enum Builtin {
    Expert(ExpertLibrary),
    Replay(ReplayLibrary),
    Random,
    Noop,
}

fn prepare(choice: &PolicyChoice, options: &EvalOptions) -> Result<Prepared, EvalError> {
    Ok(match choice {
        PolicyChoice::Remote { url } => Prepared::Remote(Box::new(
            RemotePolicy::connect(url, options.timeout).map_err(EvalError::Unreachable)?,
        )),
        PolicyChoice::Expert => Prepared::Builtin(Builtin::Expert(ExpertLibrary::builtin()?)),
        PolicyChoice::Replay { dataset } => {
            let library =
                ReplayLibrary::load(dataset).map_err(|source| EvalError::ReplayDataset {
                    path: dataset.clone(),
                    source,
                })?;
            if let Some(&task) = options.tasks.iter().find(|t| library.count(**t) == 0) {
                return Err(EvalError::NoDemonstration {
                    path: dataset.clone(),
                    task,
                });
            }
            Prepared::Builtin(Builtin::Replay(library))
        }
        PolicyChoice::Random => Prepared::Builtin(Builtin::Random),
        PolicyChoice::Noop => Prepared::Builtin(Builtin::Noop),
    })
}

/// What one trial did, and its episode when it was recorded.
struct Outcome {
    result: TrialResult,
    episode: Option<Episode>,
}

/// Runs trial `trial` with `agent` on `env`, fresh from `instance` with its first
/// `observation`; `record` keeps every rendered step.
/// The contact events of a trial's history, objects by name.
fn trial_events(history: &TrialHistory, instance: &TaskInstance) -> Vec<TrialEvent> {
    (history.events().iter())
        .map(|e| TrialEvent {
            step: e.step_index,
            event: e.kind.name(),
            object: (e.object)
                .and_then(|i| instance.scene.objects.get(i))
                .map(|o| o.name.clone()),
        })
        .collect()
}

/// Why a trial ended without success (empty on success): the policy's error, the step limit,
/// a failure nothing could undo, or the policy stopping.
fn trial_reason(
    failure: Option<&str>,
    verdict: &Verdict,
    (taken, limit): (u32, u32),
    done: bool,
) -> String {
    match (failure, verdict.success) {
        (Some(why), _) => format!("policy: {why}"),
        (None, true) => String::new(),
        (None, false) if taken >= limit => {
            format!("step limit {limit} reached: {}", verdict.reason)
        }
        (None, false) if done => verdict.reason.clone(),
        (None, false) => format!("policy stopped after {taken} steps: {}", verdict.reason),
    }
}

fn run_trial(
    (mut env, mut observation): (Env, EnvObservation),
    instance: &TaskInstance,
    trial: u32,
    agent: &mut dyn Agent,
    record: bool,
) -> Outcome {
    let limit = env.max_steps();
    let mut tracker = ProgressTracker::new(instance, &observation.sim);
    let mut verdict = env.verdict();
    let mut steps = Vec::new();
    let mut failure = None;
    let mut clipped_steps = 0;
    let mut done = verdict.success;
    while env.steps() < limit && !done {
        let command = match agent.act(&observation, &instance.instruction) {
            Ok(Some(command)) => command,
            Ok(None) => break,
            Err(why) => {
                failure = Some(why);
                break;
            }
        };
        let (step, open) = match command {
            Command::Physical(action) => (env.step(&action), action.gripper >= 0.5),
            Command::Native(command) => (
                env.step_native(&command),
                command.jaw_command() == JawCommand::Open,
            ),
        };
        if record {
            steps.push(dataset_step(&mut observation, &step.observation, open));
        }
        clipped_steps += u32::from(step.clipped);
        tracker.update(&step.observation.sim);
        done = step.done;
        verdict = step.verdict;
        observation = step.observation;
    }
    let taken = env.steps();
    let reason = trial_reason(failure.as_deref(), &verdict, (taken, limit), done);
    let task = instance.task;
    let dt_secs = crate::sim::SimConfig::default().timing.control_dt_secs();
    let progress = tracker.finish(
        instance,
        &observation.sim,
        verdict.success,
        failure.is_some(),
        (taken, dt_secs),
    );
    let result = TrialResult {
        task_id: task.code().into(),
        variant: "none".into(),
        perturbation: Default::default(),
        trial,
        seed: instance.seed,
        instruction: instance.instruction.clone(),
        success: verdict.success,
        steps: taken,
        reason,
        policy_error: failure.is_some(),
        clipped_steps,
        // To the micrometre: the figure, not float noise.
        peak_penetration_mm: (observation.sim.history.peak_penetration_m * 1e6).round() / 1e3,
        events: trial_events(&observation.sim.history, instance),
        replayed_episode: None,
        recording: None,
        progress,
    };
    let episode = record.then(|| Episode {
        encoded: Vec::new(),
        image_stats: Vec::new(),
        stored_rows: None,
        meta: EpisodeMeta {
            index: u64::from(trial),
            task_code: task.code().into(),
            task_name: task.name().into(),
            level: task.level(),
            instruction: instance.instruction.clone(),
            seed: instance.seed,
            attempts: 1,
            success: verdict.success,
            task_changes: Vec::new(),
            fields: serde_json::Map::new(),
        },
        steps,
    });
    Outcome { result, episode }
}

/// The dataset step of `before` (its images taken) and the achieved change to `after`.
fn dataset_step(before: &mut EnvObservation, after: &EnvObservation, open: bool) -> Step {
    let Images { rgb, depth_m, mask } = before.images.take().unwrap_or_default();
    let mut action = [0f32; 7];
    for axis in 0..3 {
        action[axis] = after.state[axis] - before.state[axis];
        let turn = f64::from(after.state[axis + 3] - before.state[axis + 3]);
        action[axis + 3] = wrap_angle(turn) as f32;
    }
    // Roll and pitch do not change (the action space keeps the tool pointing down): what the
    // f32 state shows of them is rounding (at most a few ulps), recorded as exact zeros.
    for turn in &mut action[3..5] {
        if turn.abs() < 1e-5 {
            *turn = 0.0;
        }
    }
    action[6] = if open { 1.0 } else { 0.0 };
    Step {
        rgb,
        depth_m,
        mask,
        state: before.state,
        action,
        environment_state: before.environment_state,
        extras: std::mem::take(&mut before.extras),
        other: Vec::new(),
    }
}

/// One trial to run: its scene and what its variant drew for it.
pub(super) struct TrialSetup {
    pub(super) instance: TaskInstance,
    pub(super) drawn: Drawn,
    /// The variant's name ("none" unperturbed).
    pub(super) variant: String,
}

/// Trial `trial` of `task` under `variant`: the unperturbed trial's seed, the variant drawn
/// from it and applied to the scene (spawn, distractors, instruction, the instrument's start).
pub(super) fn trial_setup(
    options: &EvalOptions,
    task: TaskId,
    variant: &Variant,
    trial: u32,
) -> Result<TrialSetup, EvalError> {
    let seed = trial_seed(options.seed, task, trial);
    let drawn = variant.draw(Dimensions::v1(), seed);
    let mut instance = task.instance(seed, &drawn.task_config(options.task_config(task)))?;
    let default_tip_m = crate::sim::SimConfig::default()
        .world_from_start_tip
        .translation
        .vector;
    drawn.apply_to_instance(&mut instance, default_tip_m);
    Ok(TrialSetup {
        instance,
        drawn,
        variant: variant.name(),
    })
}

/// The trials of `task` under `variant`.
fn setups(
    options: &EvalOptions,
    task: TaskId,
    variant: &Variant,
) -> Result<Vec<TrialSetup>, EvalError> {
    (0..options.trials)
        .map(|i| trial_setup(options, task, variant, i))
        .collect()
}

/// Progress: called with a task and its trials finished so far.
pub type Progress<'a> = &'a (dyn Fn(TaskId, u32) + Sync);

/// Evaluates `choice` on `options.tasks`, `options.trials` trials each, writes `results.json`,
/// `results.csv`, `results.md` and the failure recordings into `options.out`, and returns the
/// report.
pub fn evaluate(
    choice: &PolicyChoice,
    options: &EvalOptions,
    progress: Progress,
) -> Result<EvalReport, EvalError> {
    if options.trials == 0 || options.tasks.is_empty() {
        return Err(EvalError::Options(
            "nothing to evaluate: give at least one task and one trial".into(),
        ));
    }
    if options.out.is_file() {
        return Err(EvalError::Options(format!(
            "{} is a file; the output must be a folder",
            options.out.display()
        )));
    }
    let mut prepared = prepare(choice, options)?;
    // Held until the results are written: no other run writes into the folder meanwhile.
    let (_lock, mut journal) = claim_out(options, &identity(choice, options))?;
    let resumed_trials = journal.count();
    let mut rows = Vec::new();
    let mut trials = Vec::new();
    for (v, variant) in options.variants().iter().enumerate() {
        let name = variant.name();
        for &task in &options.tasks {
            let setups = setups(options, task, variant)?;
            let offset = v as u32 * options.trials;
            let progress: Progress = &|task, done| progress(task, offset + done);
            let done = journal.done(&name, task.code()).to_vec();
            let results = match &mut prepared {
                _ if done.len() == setups.len() => {
                    progress(task, options.trials);
                    done
                }
                Prepared::Remote(policy) => {
                    let run = (&setups[..], options, progress);
                    run_remote(policy, run, &done, &mut journal)?
                }
                Prepared::Builtin(builtin) => {
                    let results = run_builtin(builtin, &setups, options, progress)?;
                    journal.record(&results)?;
                    results
                }
            };
            let mut row = TaskResult::of(task, &results);
            row.variant.clone_from(&name);
            rows.push(row);
            trials.extend(results);
        }
    }
    super::results::set_drops(&mut rows);
    let metadata = match &prepared {
        Prepared::Remote(policy) => metadata_json(&policy.metadata),
        _ => serde_json::Value::Null,
    };
    let label = (options.name.clone())
        .or_else(|| served_name(&metadata))
        .unwrap_or_else(|| choice.name());
    let mut report = EvalReport::new(label, metadata, options_json(choice, options), rows, trials);
    report.suite = options.suite.as_ref().map(Suite::json);
    report.resumed_trials = resumed_trials;
    for (name, text) in [
        ("results.json", report.json()),
        ("results.csv", report.csv()),
        ("results.md", report.markdown()),
    ] {
        write(options, name, text.as_bytes())?;
    }
    write(options, "results.png", &results_png(&report, options)?)?;
    Ok(report)
}

/// The name a policy server gives itself in its metadata (`name`, `policy_name` or `policy`,
/// the first that is a short text), which labels its results.
fn served_name(metadata: &serde_json::Value) -> Option<String> {
    ["name", "policy_name", "policy"]
        .iter()
        .find_map(|key| super::options::policy_label(metadata.get(key)?.as_str()?))
}

/// `results.png`: the success rates with their intervals, grouped by level; a suite's run as
/// its task x variant heatmap.
fn results_png(report: &EvalReport, options: &EvalOptions) -> Result<Vec<u8>, EvalError> {
    use super::chart::{Chart, RunRates, TaskRate, chart_of, heatmap_of};
    let rates: Vec<TaskRate> = (report.tasks.iter())
        .map(|t| TaskRate {
            task_id: t.task_id.clone(),
            level: t.level,
            success_rate: t.success_rate,
            ci95_low: t.ci95_low,
            ci95_high: t.ci95_high,
            variant: t.variant.clone(),
            success_drop: t.success_drop,
            trials: t.trials,
            successes: t.successes,
            stages: (t.stages.iter())
                .map(|(stage, n)| ((*stage).to_string(), *n))
                .collect(),
        })
        .collect();
    let run = RunRates {
        policy: report.policy.clone(),
        tasks: rates,
    };
    let names = std::slice::from_ref(&report.policy);
    let runs = std::slice::from_ref(&run);
    let title = |what: &str| {
        format!(
            "{}: {what}, 95 % interval ({} trials a task)",
            report.policy, options.trials
        )
    };
    let chart = match heatmap_of(&title("success rate per variant and task"), runs, names) {
        Some(map) => Chart::Heatmap(map),
        None => Chart::Rates(chart_of(&title("success rate per task"), runs, names)),
    };
    let encode = |e| EvalError::Write {
        path: options.out.join("results.png"),
        source: crate::export::ExportError::Encode {
            what: "results.png".into(),
            source: Box::new(e),
        },
    };
    chart.canvas().png().map_err(encode)
}

/// The results' files in `out` (a run writes nothing else).
const RESULT_FILES: [&str; 4] = ["results.json", "results.csv", "results.md", "results.png"];
const FAILURES: &str = "failures";

/// What names a run in its journal: what shapes its results (the policy, the options, the
/// suite, the recordings kept, the camera, surgvla's version).
fn identity(choice: &PolicyChoice, options: &EvalOptions) -> serde_json::Value {
    serde_json::json!({
        "evaluation": options_json(choice, options),
        "suite": options.suite.as_ref().map(Suite::json),
        "recordings_per_task": options.recordings_per_task,
        "name": options.name,
        "render_builtin": options.render_builtin,
        "camera": camera_json(&options.camera),
        "generator": format!("surgvla {}", env!("CARGO_PKG_VERSION")),
    })
}

/// The camera as the journal names it: intrinsics and `world_from_camera` (row-major 4x4).
fn camera_json(camera: &crate::render::Camera) -> serde_json::Value {
    let pose = camera.world_from_camera.to_homogeneous();
    let rows: Vec<[f64; 4]> = (0..4)
        .map(|r| [pose[(r, 0)], pose[(r, 1)], pose[(r, 2)], pose[(r, 3)]])
        .collect();
    serde_json::json!({
        "width_px": camera.width_px,
        "height_px": camera.height_px,
        "fx_px": camera.fx_px,
        "fy_px": camera.fy_px,
        "cx_px": camera.cx_px,
        "cy_px": camera.cy_px,
        "near_m": camera.near_m,
        "far_m": camera.far_m,
        "world_from_camera": rows,
    })
}

/// Takes `options.out` for this run (created if needed and locked) and opens its journal:
/// refused when it holds files that are not results, or an earlier run's results or journal,
/// unless `resume` (an interrupted run of the same evaluation, continued from its journal) or
/// `replace` (then those are removed: the results files, the journal and the failure
/// recordings, nothing else, never through a link).
fn claim_out(
    options: &EvalOptions,
    identity: &serde_json::Value,
) -> Result<(std::fs::File, Journal), EvalError> {
    let out = &options.out;
    let write = |source| EvalError::Write {
        path: out.clone(),
        source,
    };
    std::fs::create_dir_all(out).map_err(|e| write(crate::export::ExportError::io(out)(e)))?;
    let lock = crate::export::dir::lock(out).map_err(write)?;
    let entries =
        std::fs::read_dir(out).map_err(|e| write(crate::export::ExportError::io(out)(e)))?;
    let mut ours = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let kind = entry.file_type().ok();
        let file = kind.is_some_and(|k| k.is_file())
            && (RESULT_FILES.contains(&name.as_str()) || name == JOURNAL);
        let failures = kind.is_some_and(|k| k.is_dir()) && name == FAILURES;
        if !(file || failures) {
            return Err(EvalError::Options(format!(
                "{} holds {name}, which is not an evaluation's result; choose an empty or new folder",
                out.display()
            )));
        }
        ours.push(entry.path());
    }
    let journaled = ours.iter().any(|p| p.ends_with(JOURNAL));
    if options.resume && journaled {
        return Ok((lock, Journal::resume(out, identity)?));
    }
    if !ours.is_empty() && !options.replace {
        let finished = ours.iter().any(|p| p.ends_with("results.json"));
        return Err(EvalError::Options(match super::journal::scored(out) {
            Some(trials) if !finished => format!(
                "{} holds an interrupted evaluation ({trials} trial{} scored); give --resume to continue it, or --replace to start over",
                out.display(),
                if trials == 1 { "" } else { "s" }
            ),
            _ => format!(
                "{} holds the results of another run; give --replace to replace them, or choose an empty or new folder",
                out.display()
            ),
        }));
    }
    for path in ours {
        if path.ends_with(FAILURES) {
            remove_recordings(&path).map_err(write)?;
        } else {
            std::fs::remove_file(&path)
                .map_err(|e| write(crate::export::ExportError::io(&path)(e)))?;
        }
    }
    Ok((lock, Journal::create(out, identity)?))
}

/// Removes the failure recordings (`*.mcap` files) of an earlier run, then the folder if empty.
fn remove_recordings(folder: &std::path::Path) -> Result<(), crate::export::ExportError> {
    let entries = std::fs::read_dir(folder).map_err(crate::export::ExportError::io(folder))?;
    for entry in entries.flatten() {
        let path = entry.path();
        let recording = entry.file_type().is_ok_and(|k| k.is_file())
            && path.extension().is_some_and(|e| e == "mcap");
        if recording {
            std::fs::remove_file(&path).map_err(crate::export::ExportError::io(&path))?;
        }
    }
    let _ = std::fs::remove_dir(folder);
    Ok(())
}

fn write(options: &EvalOptions, relative: &str, bytes: &[u8]) -> Result<(), EvalError> {
    let path = options.out.join(relative);
    crate::export::write_atomically(&path, bytes)
        .map(|_| ())
        .map_err(|source| EvalError::Write { path, source })
}

fn options_json(choice: &PolicyChoice, options: &EvalOptions) -> serde_json::Value {
    let spawn: serde_json::Map<String, serde_json::Value> = options
        .tasks
        .iter()
        .map(|&t| {
            (
                t.code().to_string(),
                options.task_config(t).spawn_scale.into(),
            )
        })
        .collect();
    let remote = matches!(choice, PolicyChoice::Remote { .. });
    let mut json = serde_json::json!({
        "policy": choice.name(),
        "tasks": options.tasks.iter().map(|t| t.code()).collect::<Vec<_>>(),
        "trials": options.trials,
        "seed": options.seed,
        "seed_stream": "eval/<task id> (disjoint from collection's)",
        "instructions": options.instruction.name(),
        "distractors": options.distractors,
        "spawn_scale": spawn,
    });
    if remote {
        json["sent"] = serde_json::json!({
            "observation/image": true,
            "observation/state": true,
            "prompt": true,
            "observation/depth": options.send.depth,
            "observation/environment_state": options.send.environment_state,
        });
        json["replan_steps"] = options.replan_steps.map_or("chunk".into(), Into::into);
        json["timeout_secs"] = options.timeout.as_secs_f64().into();
    }
    if let PolicyChoice::Replay { dataset } = choice {
        json["dataset"] = dataset.display().to_string().into();
    }
    json
}

/// The environment of a task's trials.
pub(super) fn env_options(options: &EvalOptions, task: TaskId, render: bool) -> EnvOptions {
    EnvOptions {
        task: options.task_config(task),
        camera: options.camera,
        render: if render {
            EnvOptions::default().render
        } else {
            None
        },
        ..EnvOptions::default()
    }
}

/// The environment of one trial: the task's, with its variant's camera, appearance and image
/// effects.
pub(super) fn trial_env(options: &EvalOptions, setup: &TrialSetup, render: bool) -> EnvOptions {
    let base = env_options(options, setup.instance.task, render);
    EnvOptions {
        camera: setup.drawn.camera(&base.camera),
        appearance: Some(setup.drawn.appearance),
        effects: setup.drawn.effects,
        ..base
    }
}

/// Trials of one task with a built-in policy: headless and in parallel, then the first failures
/// re-run with rendering and recorded.
fn run_builtin(
    builtin: &Builtin,
    setups: &[TrialSetup],
    options: &EvalOptions,
    progress: Progress,
) -> Result<Vec<TrialResult>, EvalError> {
    let Some(task) = setups.first().map(|s| s.instance.task) else {
        return Ok(Vec::new());
    };
    let done = AtomicU32::new(0);
    let run = |i: usize, render: bool, record: bool| -> Result<Outcome, EvalError> {
        let env = trial_env(options, &setups[i], render);
        builtin_trial(builtin, &setups[i].instance, i as u32, &env, record)
    };
    let pool = crate::threads::pool(options.threads.max(1))
        .map_err(|e| EvalError::Options(crate::error::chain(&e)))?;
    let mut results: Vec<TrialResult> = pool.install(|| {
        (0..setups.len())
            .into_par_iter()
            .map(|i| {
                let outcome = run(i, options.render_builtin, false)?;
                progress(task, done.fetch_add(1, Ordering::Relaxed) + 1);
                Ok(outcome.result)
            })
            .collect::<Result<_, EvalError>>()
    })?;
    for (result, setup) in results.iter_mut().zip(setups) {
        result.variant.clone_from(&setup.variant);
        result.perturbation = setup.drawn.values.clone();
    }
    let failed: Vec<usize> = (0..results.len())
        .filter(|&i| !results[i].success)
        .collect();
    for &i in failed.iter().take(options.recordings_per_task) {
        let outcome = run(i, true, true)?;
        if let Some(episode) = outcome.episode {
            results[i].recording = Some(save_recording(options, &setups[i], &episode)?);
        }
    }
    Ok(results)
}

impl Builtin {
    /// The agent of a trial from its first observation, and the training episode it replays.
    fn agent(
        &self,
        instance: &TaskInstance,
        first: &EnvObservation,
    ) -> Result<(Box<dyn Agent>, Option<u64>), EvalError> {
        Ok(match self {
            Builtin::Expert(library) => {
                let plan = library.plan(instance.task)?;
                let expert = plan.expert(instance, &first.sim, instance.seed)?;
                (Box::new(ExpertAgent(expert)), None)
            }
            Builtin::Replay(library) => {
                let (agent, episode) = library.agent(instance.task, first).ok_or_else(|| {
                    EvalError::Options(format!(
                        "the replay dataset has no episode of {}",
                        instance.task
                    ))
                })?;
                (Box::new(agent), Some(episode))
            }
            Builtin::Random => (
                Box::new(RandomAgent(RandomPolicy::new(instance.seed))),
                None,
            ),
            Builtin::Noop => (Box::new(NoopAgent), None),
        })
    }
}

fn builtin_trial(
    builtin: &Builtin,
    instance: &TaskInstance,
    trial: u32,
    env: &EnvOptions,
    record: bool,
) -> Result<Outcome, EvalError> {
    let (env, first) = Env::from_instance(instance.clone(), env);
    let (mut agent, replayed) = builtin.agent(instance, &first)?;
    let mut outcome = run_trial((env, first), instance, trial, agent.as_mut(), record);
    outcome.result.replayed_episode = replayed;
    Ok(outcome)
}

/// Trials of one task with a remote policy, one at a time, rendered, each journaled once
/// scored; the first failures are kept and recorded. Trials in `done` (a resumed run's) are
/// not run again.
fn run_remote(
    policy: &mut RemotePolicy,
    (setups, options, progress): (&[TrialSetup], &EvalOptions, Progress),
    done: &[TrialResult],
    journal: &mut Journal,
) -> Result<Vec<TrialResult>, EvalError> {
    let mut results = Vec::with_capacity(setups.len());
    let mut recorded = 0;
    let size = (
        options.camera.height_px as usize,
        options.camera.width_px as usize,
    );
    for (i, setup) in setups.iter().enumerate() {
        let instance = &setup.instance;
        if let Some(scored) = done.iter().find(|t| t.trial == i as u32) {
            recorded += usize::from(scored.recording.is_some());
            progress(instance.task, i as u32 + 1);
            results.push(scored.clone());
            continue;
        }
        let env = Env::from_instance(instance.clone(), &trial_env(options, setup, true));
        let mut agent = RemoteAgent::new(policy, options.send, options.replan_steps, size);
        let record = recorded < options.recordings_per_task;
        let outcome = run_trial(env, instance, i as u32, &mut agent, record);
        let mut result = outcome.result;
        result.variant.clone_from(&setup.variant);
        result.perturbation = setup.drawn.values.clone();
        if let (false, Some(episode)) = (result.success, outcome.episode) {
            result.recording = Some(save_recording(options, setup, &episode)?);
            recorded += 1;
        }
        journal.record(std::slice::from_ref(&result))?;
        progress(instance.task, i as u32 + 1);
        results.push(result);
    }
    Ok(results)
}

/// Writes a failed trial's MCAP (images, depth, point cloud, frames, state, action, the scene's
/// meshes) under `failures/` and returns its path relative to the results folder.
fn save_recording(
    options: &EvalOptions,
    setup: &TrialSetup,
    episode: &Episode,
) -> Result<String, EvalError> {
    let instance = &setup.instance;
    // A variant's trials share the unperturbed trials' seeds: its name tells them apart.
    let variant = match setup.variant.as_str() {
        "none" => String::new(),
        name => format!("_{}", name.replace('=', "").replace(',', "_")),
    };
    let relative = format!(
        "failures/{}{variant}_trial{:03}_seed{}.mcap",
        instance.task.code(),
        episode.meta.index,
        instance.seed
    );
    let collection = Collection::of(&EvaluationRecord {
        evaluation: true,
        seed: instance.seed,
    });
    let features = FeatureSet {
        mask: true,
        ..FeatureSet::default()
    };
    let camera = setup.drawn.camera(&options.camera);
    let info = crate::view::dataset_info(&camera, features, collection);
    let meshes = crate::view::scene_meshes_at_start(&instance.scene, instance.seed, false);
    let bytes = record_episode(&info, &McapOptions::default(), episode, Some(&meshes)).map_err(
        |source| EvalError::Write {
            path: options.out.join(&relative),
            source,
        },
    )?;
    write(options, &relative, &bytes)?;
    Ok(relative)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_is_named_by_its_camera_pose_and_intrinsics() {
        let options = EvalOptions::default();
        let base = identity(&PolicyChoice::Expert, &options);
        assert_eq!(base, identity(&PolicyChoice::Expert, &options.clone()));
        let camera = &base["camera"];
        assert_eq!(camera["width_px"], options.camera.width_px);
        assert_eq!(
            camera["world_from_camera"][3],
            serde_json::json!([0.0, 0.0, 0.0, 1.0])
        );
        let mut moved = options.clone();
        moved.camera.world_from_camera.translation.vector.x += 0.001;
        let mut narrower = options.clone();
        narrower.camera.fx_px *= 1.1;
        for other in [moved, narrower] {
            assert_ne!(base, identity(&PolicyChoice::Expert, &other));
        }
    }
}
