//! The environment: one task instance in the simulator, observed the way a dataset step holds
//! it. Collection and closed-loop evaluation both drive an [`Env`], so an evaluated policy sees
//! exactly the observations it was trained on.
//!
//! [`Env::reset`] draws the task's scene for a seed and returns the first [`EnvObservation`];
//! [`Env::step`] applies a physical 7-D action and returns the next observation, whether the
//! episode is done (success, or the step limit) and the success verdict. Rendering is optional
//! ([`EnvOptions::render`]): the expert pass runs without images. This is the one place where
//! simulator state becomes the observation half of a dataset step (state, object poses, images,
//! extras); the action half, the achieved change, is known only after stepping, so `collect`
//! assembles the [`crate::episode::Step`].

use crate::assets::{Appearance, SceneAssets};
use crate::episode::{CameraInfo, MAX_OBJECTS, POSE_VALUES, StepExtras};
use crate::render::{Camera, EffectsCache, ImageEffects, RenderOptions, Renderer};
use crate::sim::{NativeCommand, Observation, PhysicalAction, SimConfig, Simulator, StepReport};
use crate::task::{SpawnError, TaskConfig, TaskId, TaskInstance, Verdict};
use crate::view::render_simulator_over_static;
use std::time::Instant;

/// How an environment is set up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvOptions {
    pub task: TaskConfig,
    pub camera: Camera,
    /// Render images into every observation (None: no images, e.g. the expert pass).
    pub render: Option<RenderOptions>,
    /// Draw a seeded appearance variation per episode.
    pub randomize_appearance: bool,
    /// This appearance instead (an evaluation's perturbation; overrides `randomize_appearance`).
    pub appearance: Option<Appearance>,
    /// Applied to every rendered frame's RGB (an evaluation's perturbation).
    pub effects: ImageEffects,
    /// Most control steps before an episode is done (None: the task's step limit).
    pub max_steps: Option<u32>,
}

impl EnvOptions {
    /// The defaults without rendering (expert passes, replay checks).
    pub fn headless() -> Self {
        EnvOptions {
            render: None,
            ..EnvOptions::default()
        }
    }
}

impl Default for EnvOptions {
    fn default() -> Self {
        EnvOptions {
            task: TaskConfig::default(),
            camera: Camera::endoscope(),
            render: Some(RenderOptions::default()),
            randomize_appearance: false,
            appearance: None,
            effects: ImageEffects::default(),
            max_steps: None,
        }
    }
}

/// The endoscope's images of one step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Images {
    /// RGB u8, row-major H x W x 3.
    pub rgb: Vec<u8>,
    /// Depth f32 metres along the optical axis, row-major H x W; 0 where nothing is in range.
    pub depth_m: Vec<f32>,
    /// Mask ids, row-major H x W.
    pub mask: Vec<u8>,
}

/// What a policy (and a dataset step) observes.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvObservation {
    /// The 7-D robot state (`observation.state`).
    pub state: [f32; 7],
    /// Object poses (`observation.environment_state`), zero-padded.
    pub environment_state: [f32; MAX_OBJECTS * POSE_VALUES],
    /// Present when the environment renders.
    pub images: Option<Images>,
    /// Joint positions and the held object (the grasp and release events come with a step).
    pub extras: StepExtras,
    /// The simulator's whole observation (what scripted experts read).
    pub sim: Observation,
}

/// What one step did.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvStep {
    pub observation: EnvObservation,
    /// The task succeeded, failed for good (a terminal failure: a distractor grasped), or the
    /// step limit was reached.
    pub done: bool,
    /// The success predicate after the step.
    pub verdict: Verdict,
    pub report: StepReport,
    /// The action was changed to fit the action space or the workspace.
    pub clipped: bool,
}

/// Seconds an environment spent, summed over its episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvTiming {
    pub physics_secs: f64,
    pub render_secs: f64,
}

/// One task instance being simulated.
pub struct Env {
    instance: TaskInstance,
    sim: Simulator,
    options: EnvOptions,
    view: Option<(SceneAssets, Renderer)>,
    /// What the image effects keep for the episode.
    effects_cache: EffectsCache,
    steps: u32,
    pub timing: EnvTiming,
}

impl Env {
    /// Draws `task`'s scene for `seed` and returns the environment and its first observation.
    pub fn reset(
        task: TaskId,
        seed: u64,
        options: &EnvOptions,
    ) -> Result<(Env, EnvObservation), SpawnError> {
        let instance = task.instance(seed, &options.task)?;
        Ok(Env::from_instance(instance, options))
    }

    /// Starts an already drawn instance.
    pub fn from_instance(instance: TaskInstance, options: &EnvOptions) -> (Env, EnvObservation) {
        let view = options.render.map(|render| {
            let appearance = match options.appearance {
                Some(given) => given,
                None if options.randomize_appearance => Appearance::randomized(instance.seed),
                None => Appearance::default(),
            };
            let assets = SceneAssets::new(&instance.scene, instance.seed, appearance);
            let renderer = Renderer::new(RenderOptions {
                lighting: appearance.lighting(render.lighting),
                ..render
            });
            (assets, renderer)
        });
        let sim = Simulator::new(SimConfig::default(), instance.scene.clone());
        let mut env = Env {
            instance,
            sim,
            options: *options,
            view,
            effects_cache: EffectsCache::default(),
            steps: 0,
            timing: EnvTiming::default(),
        };
        let observation = env.observe();
        (env, observation)
    }

    pub fn instance(&self) -> &TaskInstance {
        &self.instance
    }

    /// The step limit of an episode.
    pub fn max_steps(&self) -> u32 {
        self.options
            .max_steps
            .unwrap_or_else(|| self.instance.task.step_limit())
    }

    /// The camera as datasets record it.
    pub fn camera_info(&self) -> CameraInfo {
        crate::view::camera_info(&self.options.camera)
    }

    /// Takes back an observation's images: the next [`Env::observe`] draws into their buffers.
    pub fn recycle(&mut self, images: Images) {
        if let Some((_, renderer)) = self.view.as_mut() {
            renderer.recycle(images.rgb, images.depth_m, images.mask);
        }
    }

    /// The current observation (rendered when the environment renders).
    pub fn observe(&mut self) -> EnvObservation {
        let sim = self.sim.observation();
        let images = self.view.as_mut().map(|(assets, renderer)| {
            let started = Instant::now();
            // The environment's renderer serves this episode's scene only.
            let mut frame =
                render_simulator_over_static(assets, renderer, &self.options.camera, &self.sim);
            let index = u64::from(self.steps);
            self.options
                .effects
                .apply(&mut frame, index, &mut self.effects_cache);
            self.timing.render_secs += started.elapsed().as_secs_f64();
            Images {
                rgb: frame.rgb,
                depth_m: frame.depth_m,
                mask: frame.mask,
            }
        });
        EnvObservation {
            state: sim.state7().map(|v| v as f32),
            environment_state: environment_state(&sim),
            images,
            extras: StepExtras {
                joint_positions: sim.joint_positions.to_vec(),
                held_object: sim.bound_object.map(|i| self.object_name(i)),
                grasped: None,
                released: None,
                success_after: None,
                frames: crate::view::robot_frames(&self.sim),
            },
            sim,
        }
    }

    fn object_name(&self, index: usize) -> String {
        self.sim
            .scene()
            .objects
            .get(index)
            .map_or_else(|| format!("object {index}"), |o| o.name.clone())
    }

    /// The objects a step grasped and released, by name.
    pub fn events(&self, report: &StepReport) -> (Option<String>, Option<String>) {
        (
            report.bound.map(|i| self.object_name(i)),
            report.released.map(|i| self.object_name(i)),
        )
    }

    /// Applies a physical action (deltas + gripper 1 open / 0 closed) without observing: the
    /// step report only.
    pub fn apply(&mut self, action: &PhysicalAction) -> StepReport {
        self.timed_step(|sim| sim.step_physical(action))
    }

    /// Applies a native command (what scripted experts emit) without observing.
    pub fn apply_native(&mut self, command: &NativeCommand) -> StepReport {
        self.timed_step(|sim| sim.step_native(command))
    }

    /// One control step, counted and timed.
    fn timed_step(&mut self, step: impl FnOnce(&mut Simulator) -> StepReport) -> StepReport {
        let started = Instant::now();
        let report = step(&mut self.sim);
        self.timing.physics_secs += started.elapsed().as_secs_f64();
        self.steps += 1;
        report
    }

    /// The simulator's observation alone (no images, no dataset arrays): what a scripted
    /// expert reads each step.
    pub fn sim_observation(&self) -> Observation {
        self.sim.observation()
    }

    /// Applies a physical action within the reference's action space (see
    /// [`PhysicalAction::within_reference`]: at most 1 cm per axis, no roll or pitch, at most
    /// 30 deg of yaw; the workspace box then clips the target) and observes the result.
    /// `EnvStep::clipped` says whether the action had to be changed.
    pub fn step(&mut self, action: &PhysicalAction) -> EnvStep {
        let (action, clipped) = action.within_reference();
        let report = self.apply(&action);
        let mut step = self.observe_step(report);
        step.clipped = clipped || step.report.clipped;
        step
    }

    /// Applies a native command (a scripted expert's, a random baseline's) and observes the
    /// result.
    pub fn step_native(&mut self, command: &NativeCommand) -> EnvStep {
        let report = self.apply_native(command);
        self.observe_step(report)
    }

    /// The observation, events and verdict after a step that made `report`.
    fn observe_step(&mut self, report: StepReport) -> EnvStep {
        let mut observation = self.observe();
        (observation.extras.grasped, observation.extras.released) = self.events(&report);
        // The simulator's observation, built once for the frame, the verdict and the failure
        // check.
        let verdict = self.instance.success(&observation.sim);
        let terminal = self.instance.terminal_failure(&observation.sim).is_some();
        EnvStep {
            done: verdict.success || terminal || self.steps >= self.max_steps(),
            observation,
            clipped: report.clipped,
            verdict,
            report,
        }
    }

    /// The success predicate now.
    pub fn verdict(&self) -> Verdict {
        self.instance.success(&self.sim.observation())
    }

    /// Control steps taken since the reset.
    pub fn steps(&self) -> u32 {
        self.steps
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

#[cfg(test)]
mod tests {
    use super::*;

    fn drift(step: usize) -> PhysicalAction {
        // A slow wander with the jaws open: moves the tip, never grasps.
        let dx = if step.is_multiple_of(2) {
            0.002
        } else {
            -0.001
        };
        PhysicalAction::from_array([dx, 0.001, 0.0, 0.0, 0.0, 0.0, 1.0])
    }

    #[test]
    fn rendering_changes_nothing_but_the_images() {
        let options = EnvOptions {
            max_steps: Some(4),
            ..EnvOptions::default()
        };
        let (mut seen, first) = Env::reset(TaskId::GauzePick, 7, &options).expect("spawn");
        let (mut blind, blind_first) =
            Env::reset(TaskId::GauzePick, 7, &EnvOptions::headless()).expect("spawn");
        let images = first.images.as_ref().expect("a rendering env has images");
        let (w, h) = (
            options.camera.width_px as usize,
            options.camera.height_px as usize,
        );
        assert_eq!(
            (images.rgb.len(), images.depth_m.len(), images.mask.len()),
            (w * h * 3, w * h, w * h)
        );
        assert!(blind_first.images.is_none());
        assert_eq!(first.state, blind_first.state);
        for i in 0..4 {
            let (a, b) = (seen.step(&drift(i)), blind.step(&drift(i)));
            assert_eq!(a.observation.state, b.observation.state);
            assert_eq!(
                a.observation.environment_state,
                b.observation.environment_state
            );
            assert_eq!(a.observation.extras, b.observation.extras);
            assert_eq!(a.observation.extras.joint_positions.len(), 6);
            assert!(a.observation.images.is_some() && b.observation.images.is_none());
        }
        assert!(seen.timing.render_secs > 0.0 && blind.timing.render_secs == 0.0);
    }

    /// A policy's oversized action is executed as the reference would: 1 cm, no tilt, 30 deg.
    #[test]
    fn an_oversized_action_is_clipped_to_the_action_space() {
        let (mut env, first) =
            Env::reset(TaskId::GauzePick, 1, &EnvOptions::headless()).expect("spawn");
        let start = first.sim.state7();
        let step = env.step(&PhysicalAction::from_array([
            0.05, 0.0, -0.03, 0.0, 0.4, 1.5, 1.0,
        ]));
        assert!(step.clipped);
        let after = env.sim_observation().state7();
        assert!(
            (after[0] - start[0] - 0.01).abs() < 1e-6,
            "x moved {}",
            after[0] - start[0]
        );
        assert!(
            (after[2] - start[2] + 0.01).abs() < 1e-6,
            "z moved {}",
            after[2] - start[2]
        );
        assert!((after[3] - start[3]).abs() < 1e-9 && (after[4] - start[4]).abs() < 1e-9);
        let yaw = crate::sim::psm::wrap_angle(after[5] - start[5]);
        assert!(
            (yaw - std::f64::consts::PI / 6.0).abs() < 1e-6,
            "yaw turned {yaw}"
        );
        // Within the space: not clipped.
        let small = env.step(&PhysicalAction::from_array([
            0.004, 0.0, 0.0, 0.0, 0.0, 0.1, 1.0,
        ]));
        assert!(!small.clipped);
    }

    #[test]
    fn an_aimless_policy_is_done_at_the_step_limit_and_fails() {
        let options = EnvOptions {
            max_steps: Some(6),
            ..EnvOptions::headless()
        };
        let (mut env, _) = Env::reset(TaskId::NeedlePick, 3, &options).expect("spawn");
        assert_eq!(env.max_steps(), 6);
        let mut last = None;
        for i in 0..6 {
            let step = env.step(&drift(i));
            assert_eq!(step.done, i == 5, "step {i}");
            last = Some(step);
        }
        let last = last.expect("six steps");
        assert!(!last.verdict.success, "{}", last.verdict.reason);
        assert_eq!(env.steps(), 6);
        let (default_env, _) =
            Env::reset(TaskId::NeedlePick, 3, &EnvOptions::headless()).expect("spawn");
        assert_eq!(default_env.max_steps(), TaskId::NeedlePick.step_limit());
    }
}
