//! Recording verified episodes in two passes.
//!
//! 1. [`run_expert`]: the task's scripted expert drives the simulator with native commands (no
//!    rendering). Each step's dataset action is the state change it caused (`dx, dy, dz` m,
//!    `droll, dpitch, dyaw` rad, as f32) plus the gripper (1 while commanded open, 0 while
//!    closed, or the opt-in pulse encoding). The expert succeeds when its plan completes within
//!    the step limit and the task's success predicate holds.
//! 2. [`render_replay`]: a fresh simulator of the same instance replays the recorded *dataset
//!    actions* as physical actions and renders every step; the saved frames and states are this
//!    replay's, and the episode counts only if the predicate holds at its end too. So every
//!    saved episode is, by construction, what its own actions reproduce.

use crate::assets::{Appearance, SceneAssets};
use crate::episode::{
    CameraInfo, Episode, EpisodeMeta, GripperEncoding, MAX_OBJECTS, POSE_VALUES, Step,
};
use crate::policy::{ExpertLibrary, ExpertPlan, PlanError, Policy};
use crate::render::{Camera, RenderOptions, Renderer};
use crate::sim::psm::wrap_angle;
use crate::sim::{JawCommand, Observation, PhysicalAction, SimConfig, Simulator};
use crate::task::{SpawnError, TaskConfig, TaskId, TaskInstance, Verdict};
use crate::view::render_simulator;
use std::time::Instant;

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

/// The camera as the episode model records it (row-major 4 x 4 `world_from_camera`).
pub fn camera_info(camera: &Camera) -> CameraInfo {
    let m = camera.world_from_camera.to_homogeneous();
    let mut world_from_camera = [[0.0; 4]; 4];
    for (r, row) in world_from_camera.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    CameraInfo {
        width_px: camera.width_px,
        height_px: camera.height_px,
        fx_px: camera.fx_px,
        fy_px: camera.fy_px,
        cx_px: camera.cx_px,
        cy_px: camera.cy_px,
        world_from_camera,
    }
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
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let mut observation = sim.observation();
    let mut policy = plan.expert(instance, &observation, instance.seed)?;
    let mut physical = Vec::with_capacity(max_steps as usize);
    let mut open = Vec::with_capacity(max_steps as usize);
    let started = Instant::now();
    while !policy.is_done() && physical.len() < max_steps as usize {
        let command = policy.act(&observation);
        sim.step_native(&command);
        let next = sim.observation();
        let (before, after) = (observation.state7(), next.state7());
        let mut action = [0f32; 6];
        for axis in 0..3 {
            action[axis] = (after[axis] - before[axis]) as f32;
            action[axis + 3] = wrap_angle(after[axis + 3] - before[axis + 3]) as f32;
        }
        physical.push(action);
        open.push(command.jaw_command() == JawCommand::Open);
        observation = next;
    }
    let physics_secs = started.elapsed().as_secs_f64();
    let verdict = if policy.is_done() {
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
        physics_secs,
    })
}

/// Replays dataset actions from the instance's start, calling `before_step(sim, observation)`
/// before each step, and returns the predicate at the end with the seconds spent stepping.
pub fn replay_actions(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    gripper: GripperEncoding,
    mut before_step: impl FnMut(&Simulator, &Observation),
) -> (Verdict, f64) {
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let values: Vec<f32> = actions.iter().map(|a| a[6]).collect();
    let mut physics_secs = 0.0;
    for (action, open) in actions.iter().zip(gripper.decode(&values)) {
        before_step(&sim, &sim.observation());
        let mut values = action.map(f64::from);
        values[6] = if open { 1.0 } else { 0.0 };
        let started = Instant::now();
        sim.step_physical(&PhysicalAction::from_array(values));
        physics_secs += started.elapsed().as_secs_f64();
    }
    (instance.success(&sim.observation()), physics_secs)
}

/// Replays dataset actions without rendering: does the recorded episode reproduce success?
pub fn verify_replay(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    gripper: GripperEncoding,
) -> Verdict {
    replay_actions(instance, actions, gripper, |_, _| {}).0
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

/// Replays `actions` on `instance`, rendering every step, into episode `index`.
pub fn render_replay(
    instance: &TaskInstance,
    actions: &[[f32; 7]],
    index: u64,
    options: &RecordOptions,
) -> Recorded {
    let appearance = if options.randomize_appearance {
        Appearance::randomized(instance.seed)
    } else {
        Appearance::default()
    };
    let assets = SceneAssets::new(&instance.scene, instance.seed, appearance);
    let mut renderer = Renderer::new(RenderOptions {
        lighting: appearance.lighting(options.render.lighting),
        ..options.render
    });
    let mut steps = Vec::with_capacity(actions.len());
    let mut render_secs = 0.0;
    let (verdict, physics_secs) =
        replay_actions(instance, actions, options.gripper, |sim, observation| {
            let started = Instant::now();
            let frame = render_simulator(&assets, &mut renderer, &options.camera, sim);
            render_secs += started.elapsed().as_secs_f64();
            steps.push(Step {
                rgb: frame.rgb,
                depth_m: frame.depth_m,
                mask: frame.mask,
                state: observation.state7().map(|v| v as f32),
                action: [0.0; 7],
                environment_state: environment_state(observation),
            });
        });
    for (step, action) in steps.iter_mut().zip(actions) {
        step.action = *action;
    }
    let task = instance.task;
    Recorded {
        episode: Episode {
            meta: EpisodeMeta {
                index,
                task_code: task.code().into(),
                task_name: task.name().into(),
                level: task.level(),
                instruction: instance.instruction.clone(),
                seed: instance.seed,
                success: verdict.success,
                camera: camera_info(&options.camera),
                simulator_version: env!("CARGO_PKG_VERSION").into(),
            },
            steps,
        },
        verdict,
        physics_secs,
        render_secs,
    }
}

/// Object poses, [`MAX_OBJECTS`] x (x, y, z, qx, qy, qz, qw), zero-padded.
fn environment_state(observation: &Observation) -> [f32; MAX_OBJECTS * POSE_VALUES] {
    let mut state = [0f32; MAX_OBJECTS * POSE_VALUES];
    for (i, object) in observation.objects.iter().take(MAX_OBJECTS).enumerate() {
        let pose = object.world_from_object;
        let q = pose.rotation.coords; // (x, y, z, w)
        let values = [
            pose.translation.x,
            pose.translation.y,
            pose.translation.z,
            q[0],
            q[1],
            q[2],
            q[3],
        ];
        for (k, v) in values.iter().enumerate() {
            state[i * POSE_VALUES + k] = *v as f32;
        }
    }
    state
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
    Ok(render_replay(&instance, &expert.actions, index, options).episode)
}
