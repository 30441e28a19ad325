//! Recording episodes: run a policy in a task scene, render every step, and produce an
//! [`Episode`] with physical actions (the state change each step caused; gripper 1 while
//! commanded open, 0 while commanded closed).

use crate::assets::{Appearance, SceneAssets};
use crate::collect::demo_plan;
use crate::episode::{CameraInfo, Episode, EpisodeMeta, MAX_OBJECTS, POSE_VALUES, Step};
use crate::policy::Policy;
use crate::render::{Camera, RenderOptions, Renderer};
use crate::sim::psm::wrap_angle;
use crate::sim::{JawCommand, SimConfig, Simulator};
use crate::task::TaskId;
use crate::view::render_simulator;

/// How episodes are recorded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordOptions {
    pub camera: Camera,
    pub render: RenderOptions,
    /// Draw a seeded appearance variation per episode.
    pub randomize_appearance: bool,
    /// Most control steps (defaults to the task's step limit when None).
    pub max_steps: Option<u32>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            camera: Camera::endoscope(),
            render: RenderOptions::default(),
            randomize_appearance: false,
            max_steps: None,
        }
    }
}

/// The seed of episode `k` of `task` in a collection seeded with `seed`.
pub fn episode_seed(seed: u64, task: TaskId, k: u64) -> u64 {
    let mut rng =
        crate::rng::SplitMix64::stream(seed ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15), task.code());
    rng.next_u64()
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

/// Records one episode of `task` with the demo policy.
pub fn record_episode(task: TaskId, seed: u64, index: u64, options: &RecordOptions) -> Episode {
    let scene = task.scene(seed);
    let mut sim = Simulator::new(SimConfig::default(), scene.clone());
    let appearance = if options.randomize_appearance {
        Appearance::randomized(seed)
    } else {
        Appearance::default()
    };
    let assets = SceneAssets::new(&scene, seed, appearance);
    let mut renderer = Renderer::new(RenderOptions {
        lighting: appearance.lighting(options.render.lighting),
        ..options.render
    });
    let mut policy = demo_plan(&sim);
    let max_steps = options.max_steps.unwrap_or_else(|| task.step_limit());
    let mut steps = Vec::new();
    let mut observation = sim.observation();
    for _ in 0..max_steps {
        if policy.is_done() {
            break;
        }
        let frame = render_simulator(&assets, &mut renderer, &options.camera, &sim);
        let command = policy.act(&observation);
        sim.step_native(&command);
        let next = sim.observation();
        let (before, after) = (observation.state7(), next.state7());
        let mut action = [0f32; 7];
        for axis in 0..3 {
            action[axis] = (after[axis] - before[axis]) as f32;
            action[axis + 3] = wrap_angle(after[axis + 3] - before[axis + 3]) as f32;
        }
        action[6] = if command.jaw_command() == JawCommand::Open {
            1.0
        } else {
            0.0
        };
        let mut environment_state = [0f32; MAX_OBJECTS * POSE_VALUES];
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
                environment_state[i * POSE_VALUES + k] = *v as f32;
            }
        }
        steps.push(Step {
            rgb: frame.rgb,
            depth_m: frame.depth_m,
            mask: frame.mask,
            state: before.map(|v| v as f32),
            action,
            environment_state,
        });
        observation = next;
    }
    Episode {
        meta: EpisodeMeta {
            index,
            task_code: task.code().into(),
            task_name: task.name().into(),
            level: task.level(),
            instruction: task.instruction().into(),
            seed,
            success: policy.is_done(),
            camera: camera_info(&options.camera),
            simulator_version: env!("CARGO_PKG_VERSION").into(),
        },
        steps,
    }
}
