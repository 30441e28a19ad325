//! Recording verified episodes in two passes.
//!
//! 1. [`run_expert`]: the task's scripted expert drives the simulator with native commands (no
//!    rendering). Each step's dataset action is the state change it caused (`dx, dy, dz` m,
//!    `droll, dpitch, dyaw` rad, as f32) plus the gripper (1 while commanded open, 0 while
//!    closed, or the opt-in pulse encoding). The expert succeeds when its plan completes within
//!    the step limit and the task's success predicate holds.
//! 2. [`render_replay`]: a fresh [`Env`] of the same instance replays the recorded *dataset
//!    actions* as physical actions and renders every step; the saved frames and states are this
//!    replay's, and the episode counts only if the predicate holds at its end too. So every
//!    saved episode is, by construction, what its own actions reproduce.

use crate::env::{Env, EnvOptions, Images};
use crate::episode::{Episode, EpisodeMeta, GripperEncoding, Pixels, Step};
use crate::policy::{ExpertLibrary, ExpertPlan, PlanError, Policy};
use crate::render::{Camera, RenderOptions};
use crate::sim::psm::wrap_angle;
use crate::sim::{JawCommand, PhysicalAction};
use crate::task::{SpawnError, TaskConfig, TaskId, TaskInstance, Verdict};

/// A roll or pitch change below this is the float noise of a tool that stays pointing down,
/// radians: recorded as an exact zero.
const STILL_ANGLE_RAD: f32 = 1e-9;

/// How episodes are recorded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordOptions {
    pub camera: Camera,
    pub render: RenderOptions,
    /// Draw a seeded appearance variation per episode.
    pub randomize_appearance: bool,
    /// Most control steps (defaults to the task's step limit when None).
    pub max_steps: Option<u32>,
    pub gripper: GripperEncoding,
    pub task: TaskConfig,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            camera: Camera::endoscope(),
            render: RenderOptions::default(),
            randomize_appearance: false,
            max_steps: None,
            gripper: GripperEncoding::Continuous,
            task: TaskConfig::default(),
        }
    }
}

impl RecordOptions {
    /// The environment of the rendered pass (`render`) or of the expert pass.
    pub fn env(&self, render: bool) -> EnvOptions {
        EnvOptions {
            task: self.task,
            camera: self.camera,
            render: render.then_some(self.render),
            randomize_appearance: self.randomize_appearance,
            max_steps: self.max_steps,
            ..EnvOptions::default()
        }
    }
}

/// The seed of episode slot `k` of `task` in a collection seeded with `seed`.
pub fn episode_seed(seed: u64, task: TaskId, k: u64) -> u64 {
    attempt_seed(seed, task, k, 0)
}

/// The seed of attempt `attempt` at slot `k` (attempt 0 is [`episode_seed`]): a slot whose
/// attempt fails verification moves on to the next attempt's seed, so what a slot holds depends
/// on (seed, task, k) only, never on other slots, threads or shards.
pub fn attempt_seed(seed: u64, task: TaskId, k: u64, attempt: u32) -> u64 {
    let mixed = seed
        ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ u64::from(attempt).wrapping_mul(0xd1b5_4a32_d192_ed03);
    crate::rng::SplitMix64::stream(mixed, task.code()).next_u64()
}

/// What the expert pass produced.
#[derive(Clone, Debug, PartialEq)]
pub struct ExpertRun {
    /// One dataset action per step.
    pub actions: Vec<[f32; 7]>,
    /// The predicate at the end (a failure when the plan did not finish within the limit).
    pub verdict: Verdict,
    /// Seconds spent stepping the simulator.
    pub physics_secs: f64,
}

/// Runs `plan` on `instance` for at most `max_steps` steps and records the dataset actions.
pub fn run_expert(
    instance: &TaskInstance,
    plan: &ExpertPlan,
    max_steps: u32,
    gripper: GripperEncoding,
) -> Result<ExpertRun, PlanError> {
    let (mut env, first) = Env::from_instance(instance.clone(), &EnvOptions::headless());
    let mut observation = first.sim;
    let mut policy = plan.expert(instance, &observation, instance.seed)?;
    let mut physical = Vec::with_capacity(max_steps as usize);
    let mut open = Vec::with_capacity(max_steps as usize);
    let mut terminal = None;
    while !policy.is_done() && physical.len() < max_steps as usize {
        let command = policy.act(&observation);
        env.apply_native(&command);
        let next = env.sim_observation();
        let (before, after) = (observation.state7(), next.state7());
        let mut action = [0f32; 6];
        for axis in 0..3 {
            action[axis] = (after[axis] - before[axis]) as f32;
            action[axis + 3] = wrap_angle(after[axis + 3] - before[axis + 3]) as f32;
        }
        // The tool stays pointing down: roll and pitch change by float noise (~1e-15 rad),
        // written as exact zeros so a reader sees constant dimensions.
        for delta in &mut action[3..5] {
            if delta.abs() < STILL_ANGLE_RAD {
                *delta = 0.0;
            }
        }
        physical.push(action);
        open.push(command.jaw_command() == JawCommand::Open);
        observation = next;
        terminal = instance.terminal_failure(&observation);
        if terminal.is_some() {
            break;
        }
    }
    let verdict = if let Some(failure) = terminal {
        failure
    } else if policy.is_done() {
        instance.success(&observation)
    } else {
        Verdict {
            success: false,
            reason: format!(
                "plan unfinished after {max_steps} steps (waypoint {})",
                policy.controller().current_index()
            ),
        }
    };
    let actions = physical
        .iter()
        .zip(gripper.encode(&open))
        .map(|(p, g)| [p[0], p[1], p[2], p[3], p[4], p[5], g])
        .collect();
    Ok(ExpertRun {
        actions,
        verdict,
        physics_secs: env.timing.physics_secs,
    })
}

/// The physical actions that dataset actions encode (the gripper decoded over the sequence).
fn physical_actions(actions: &[[f32; 7]], gripper: GripperEncoding) -> Vec<PhysicalAction> {
    let values: Vec<f32> = actions.iter().map(|a| a[6]).collect();
    actions
        .iter()
        .zip(gripper.decode(&values))
        .map(|(action, open)| {
            let mut values = action.map(f64::from);
            values[6] = if open { 1.0 } else { 0.0 };
            PhysicalAction::from_array(values)
        })
        .collect()
}

/// Replays dataset actions without rendering: does the recorded episode reproduce success?
pub fn verify_replay(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    gripper: GripperEncoding,
) -> Verdict {
    let (mut env, _) = Env::from_instance(instance.clone(), &EnvOptions::headless());
    for action in physical_actions(actions, gripper) {
        env.apply(&action);
    }
    env.verdict()
}

/// A rendered replay.
#[derive(Clone, Debug, PartialEq)]
pub struct Recorded {
    pub episode: Episode,
    /// The predicate at the end of the replay (also `episode.meta.success`).
    pub verdict: Verdict,
    pub physics_secs: f64,
    pub render_secs: f64,
}

/// Replays `actions` on `instance`, rendering every step, into episode `index` (its meta says
/// `attempts` expert attempts were made for it).
pub fn render_replay(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    index: u64,
    attempts: u32,
    options: &RecordOptions,
) -> Recorded {
    let kept = render_replay_with(instance, actions, index, attempts, options, |_| {
        Ok::<Vec<Pixels>, std::convert::Infallible>(Vec::new())
    });
    match kept {
        Ok(recorded) => recorded,
        Err(never) => match never {},
    }
}

/// [`render_replay`] handing each step to `on_frame` as soon as it is recorded (with its
/// images, in step order). `on_frame` may take the step's pixels (the step is kept without
/// them) and returns image buffers it is done with, which later frames are drawn into.
pub fn render_replay_with<E>(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    index: u64,
    attempts: u32,
    options: &RecordOptions,
    mut on_frame: impl FnMut(&mut Step) -> Result<Vec<Pixels>, E>,
) -> Result<Recorded, E> {
    let (mut env, mut observation) = Env::from_instance(instance.clone(), &options.env(true));
    let physical = physical_actions(actions, options.gripper);
    let mut steps = Vec::with_capacity(actions.len());
    for (i, (action, dataset_action)) in physical.iter().zip(actions).enumerate() {
        // The observation before the step, the action and what the step did make one dataset
        // step. The observation after the last step is not needed (and not rendered).
        let report = env.apply(action);
        let Images { rgb, depth_m, mask } = observation.images.take().unwrap_or_default();
        let mut extras = std::mem::take(&mut observation.extras);
        (extras.grasped, extras.released) = env.events(&report);
        extras.success_after = Some(env.verdict().success);
        let mut step = Step {
            rgb,
            depth_m,
            mask,
            state: observation.state,
            action: *dataset_action,
            environment_state: observation.environment_state,
            extras,
            other: Vec::new(),
        };
        for Pixels { rgb, depth_m, mask } in on_frame(&mut step)? {
            env.recycle(Images { rgb, depth_m, mask });
        }
        steps.push(step);
        if i + 1 < physical.len() {
            observation = env.observe();
        }
    }
    let verdict = env.verdict();
    let task = instance.task;
    Ok(Recorded {
        episode: Episode {
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
            meta: EpisodeMeta {
                index,
                task_code: task.code().into(),
                task_name: task.name().into(),
                level: task.level(),
                instruction: instance.instruction.clone(),
                seed: instance.seed,
                attempts,
                success: verdict.success,
                task_changes: Vec::new(),
                fields: serde_json::Map::new(),
            },
            steps,
        },
        verdict,
        physics_secs: env.timing.physics_secs,
        render_secs: env.timing.render_secs,
    })
}

/// Why an episode could not be recorded.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Spawn(#[from] SpawnError),
}

/// Records one episode of `task` with its expert (unverified; `meta.success` says whether the
/// replay succeeded): the building block of tests and benchmarks.
pub fn record_episode(
    library: &ExpertLibrary,
    task: TaskId,
    seed: u64,
    index: u64,
    options: &RecordOptions,
) -> Result<Episode, RecordError> {
    let instance = task.instance(seed, &options.task)?;
    let max_steps = options.max_steps.unwrap_or_else(|| task.step_limit());
    let expert = run_expert(&instance, library.plan(task)?, max_steps, options.gripper)?;
    Ok(render_replay(&instance, &expert.actions, index, 1, options).episode)
}

/// Why recording an episode as MCAP failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordMcapError {
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error(transparent)]
    Export(#[from] crate::export::ExportError),
}

/// Simulates one episode of `task` with its expert (as `collect` records it) and returns it with
/// its MCAP recording: every dataset topic plus the instrument's frames on `/tf` and the scene's
/// meshes (organs, tray, objects, instrument) on `/scene`.
pub fn record_mcap(
    library: &ExpertLibrary,
    task: TaskId,
    seed: u64,
    options: &RecordOptions,
    info: &crate::export::DatasetInfo,
) -> Result<(Episode, Vec<u8>), RecordMcapError> {
    let episode = record_episode(library, task, seed, 0, options)?;
    let instance = task
        .instance(seed, &options.task)
        .map_err(RecordError::from)?;
    let meshes =
        crate::view::scene_meshes_at_start(&instance.scene, seed, options.randomize_appearance);
    let options = crate::export::mcap::McapOptions::default();
    let bytes = crate::export::mcap::record_episode(info, &options, &episode, Some(&meshes))?;
    Ok((episode, bytes))
}
