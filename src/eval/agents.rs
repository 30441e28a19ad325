//! The policies an evaluation can score, behind one [`Agent`] trait: each gets the observation
//! an [`Env`](crate::env::Env) made (what a dataset step holds) and the instruction, and returns
//! the next command, or None when it has nothing left to do.
//!
//! - [`RemoteAgent`]: a policy behind openpi's protocol; it is sent the endoscope image, the
//!   7-D state and the prompt (plus depth and object poses when asked) and answers 7-D dataset
//!   actions (deltas + gripper 1 open / 0 closed), one or a chunk; the first `replan_steps` of
//!   a chunk run before it is asked again.
//! - [`ExpertAgent`]: the task's scripted expert (native commands), the upper bound.
//! - [`ReplayAgent`]: the actions of the training episode of the same task whose initial object
//!   positions are nearest ([`ReplayLibrary`]), open loop.
//! - random (seeded uniform native commands) and no-op (zero deltas, jaws open): lower bounds.

use super::numpy::{Request, decode_actions};
use super::remote::RemotePolicy;
use crate::env::EnvObservation;
use crate::episode::{MAX_OBJECTS, POSE_VALUES};
use crate::export::{ExportError, open_source};
use crate::policy::{ExpertPolicy, Policy, RandomPolicy};
use crate::sim::{NativeCommand, PhysicalAction};
use crate::task::TaskId;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;

/// What an agent does next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// A 7-D dataset action: what a learned policy outputs.
    Physical(PhysicalAction),
    /// A native command: what scripted experts and the random baseline emit.
    Native(NativeCommand),
}

/// A policy under evaluation.
pub trait Agent {
    /// The command for this observation; None ends the trial; an error fails it with that
    /// reason (the evaluation goes on).
    fn act(
        &mut self,
        observation: &EnvObservation,
        prompt: &str,
    ) -> Result<Option<Command>, String>;
}

/// The physical action of a 7-D dataset action with a continuous gripper.
pub fn physical(action: &[f32; 7]) -> PhysicalAction {
    PhysicalAction::from_array(action.map(f64::from))
}

/// Zero deltas with the jaws open, every step.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoopAgent;

impl Agent for NoopAgent {
    fn act(&mut self, _: &EnvObservation, _: &str) -> Result<Option<Command>, String> {
        Ok(Some(Command::Physical(physical(&[
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ]))))
    }
}

/// Seeded uniform native commands (never done).
#[derive(Clone, Debug)]
pub struct RandomAgent(pub RandomPolicy);

impl Agent for RandomAgent {
    fn act(&mut self, observation: &EnvObservation, _: &str) -> Result<Option<Command>, String> {
        Ok(Some(Command::Native(self.0.act(&observation.sim))))
    }
}

/// The task's scripted expert; done when its plan is.
#[derive(Clone, Debug)]
pub struct ExpertAgent(pub ExpertPolicy);

impl Agent for ExpertAgent {
    fn act(&mut self, observation: &EnvObservation, _: &str) -> Result<Option<Command>, String> {
        if self.0.is_done() {
            return Ok(None);
        }
        Ok(Some(Command::Native(self.0.act(&observation.sim))))
    }
}

/// Plays a list of actions, then stops.
#[derive(Clone, Debug)]
pub struct ReplayAgent {
    actions: std::vec::IntoIter<PhysicalAction>,
}

impl Agent for ReplayAgent {
    fn act(&mut self, _: &EnvObservation, _: &str) -> Result<Option<Command>, String> {
        Ok(self.actions.next().map(Command::Physical))
    }
}

/// One training episode as the replay baseline uses it.
#[derive(Clone, Debug)]
struct Demonstration {
    episode_index: u64,
    /// Initial object positions (x, y, z per object slot).
    positions_m: Vec<f32>,
    actions: Vec<PhysicalAction>,
}

/// The training episodes of a dataset by task, for the replay baseline.
#[derive(Clone, Debug, Default)]
pub struct ReplayLibrary {
    by_task: BTreeMap<String, Vec<Demonstration>>,
    /// Episodes read.
    pub episodes: u64,
}

/// Object positions of an environment state, the orientation values left out.
fn positions(environment_state: &[f32]) -> Vec<f32> {
    environment_state
        .chunks_exact(POSE_VALUES)
        .take(MAX_OBJECTS)
        .flat_map(|pose| pose[..3].to_vec())
        .collect()
}

impl ReplayLibrary {
    /// Reads every episode of the dataset at `path` (any format `convert` reads) and keeps its
    /// task, initial object positions and actions (the gripper decoded as the dataset encodes
    /// it).
    pub fn load(path: &Path) -> Result<ReplayLibrary, ExportError> {
        let source = open_source(path)?;
        let encoding = (source.info().collection.as_ref())
            .and_then(|c| c.gripper_encoding())
            .unwrap_or_default();
        let mut library = ReplayLibrary::default();
        for episode in source {
            let episode = episode?;
            library.episodes += 1;
            let Some(first) = episode.steps.first() else {
                continue;
            };
            let gripper: Vec<f32> = episode.steps.iter().map(|s| s.action[6]).collect();
            let actions = episode
                .steps
                .iter()
                .zip(encoding.decode(&gripper))
                .map(|(step, open)| {
                    let mut action = step.action;
                    action[6] = if open { 1.0 } else { 0.0 };
                    physical(&action)
                })
                .collect();
            library
                .by_task
                .entry(episode.meta.task_code.clone())
                .or_default()
                .push(Demonstration {
                    episode_index: episode.meta.index,
                    positions_m: positions(&first.environment_state),
                    actions,
                });
        }
        Ok(library)
    }

    /// Training episodes of `task`.
    pub fn count(&self, task: TaskId) -> usize {
        self.by_task.get(task.code()).map_or(0, Vec::len)
    }

    /// The agent replaying the episode of `task` whose initial object positions are nearest to
    /// `observation`'s (ties: the lower episode index), and that episode's index.
    pub fn agent(&self, task: TaskId, observation: &EnvObservation) -> Option<(ReplayAgent, u64)> {
        let here = positions(&observation.environment_state);
        let distance = |d: &Demonstration| -> f64 {
            d.positions_m
                .iter()
                .zip(&here)
                .map(|(a, b)| f64::from(a - b).powi(2))
                .sum()
        };
        let nearest = self
            .by_task
            .get(task.code())?
            .iter()
            .min_by(|a, b| distance(a).total_cmp(&distance(b)))?;
        Some((
            ReplayAgent {
                actions: nearest.actions.clone().into_iter(),
            },
            nearest.episode_index,
        ))
    }
}

/// What a remote policy is sent beyond the image, the state and the prompt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct SendExtras {
    /// `observation/depth`, float32 (H, W), metres.
    pub depth: bool,
    /// `observation/environment_state`, float32 (28,): ground-truth object poses (privileged).
    pub environment_state: bool,
}

/// A policy server asked for actions, executing `replan_steps` of each chunk.
pub struct RemoteAgent<'a> {
    pub policy: &'a mut RemotePolicy,
    pub send: SendExtras,
    /// Actions of a chunk to execute before asking again (None: all of them).
    pub replan_steps: Option<usize>,
    /// Image (height, width) in pixels.
    pub image_size: (usize, usize),
    queue: VecDeque<[f32; 7]>,
    /// Requests made.
    pub requests: u64,
}

impl<'a> RemoteAgent<'a> {
    pub fn new(
        policy: &'a mut RemotePolicy,
        send: SendExtras,
        replan_steps: Option<usize>,
        image_size: (usize, usize),
    ) -> Self {
        RemoteAgent {
            policy,
            send,
            replan_steps,
            image_size,
            queue: VecDeque::new(),
            requests: 0,
        }
    }

    /// The request for one observation.
    pub fn request(&self, observation: &EnvObservation, prompt: &str) -> Result<Vec<u8>, String> {
        let images = observation
            .images
            .as_ref()
            .ok_or("the environment does not render (a remote policy needs the image)")?;
        let (h, w) = self.image_size;
        let mut request = Request::default()
            .u8_array("observation/image", &images.rgb, &[h, w, 3])
            .f32_array("observation/state", &observation.state, &[7]);
        if self.send.depth {
            request = request.f32_array("observation/depth", &images.depth_m, &[h, w]);
        }
        if self.send.environment_state {
            let values = &observation.environment_state;
            request = request.f32_array("observation/environment_state", values, &[values.len()]);
        }
        Ok(request.text("prompt", prompt).encode())
    }
}

impl Agent for RemoteAgent<'_> {
    fn act(
        &mut self,
        observation: &EnvObservation,
        prompt: &str,
    ) -> Result<Option<Command>, String> {
        if self.queue.is_empty() {
            let request = self.request(observation, prompt)?;
            self.requests += 1;
            let reply = self
                .policy
                .infer(request)
                .map_err(|e| crate::error::chain(&e))?;
            let chunk = decode_actions(&reply).map_err(|e| {
                self.policy.disconnect();
                format!("malformed reply from {}: {e}", self.policy.url())
            })?;
            let keep = self
                .replan_steps
                .unwrap_or(chunk.len())
                .clamp(1, chunk.len());
            self.queue.extend(chunk.into_iter().take(keep));
        }
        Ok(self
            .queue
            .pop_front()
            .map(|a| Command::Physical(physical(&a))))
    }
}
