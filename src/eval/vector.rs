//! Many environments of one task stepped together: the core of the Python module's gymnasium
//! environments (`surgvla.make`, `surgvla.make_vec`), with `surgvla eval`'s scenes, step limits,
//! action clipping and success predicates, and batched observations in flat buffers.
//!
//! - Trials: resetting an environment with seed `k` starts trial `k` of `surgvla eval --seed S`
//!   ([`super::run::trial_seed`]), so a vector env seeded 0..n walks the same scenes as `eval --trials n`; an
//!   unseeded reset (and the autoreset) continues with trial `k + num_envs`.
//! - Autoreset, gymnasium 1.x's default (next step): the step after an environment's episode ended
//!   ignores its action, starts its next trial and returns that first observation, reward 0.
//! - Actions: the dataset's 7-D action, clipped as `eval` clips a policy's
//!   ([`Env::step`]), or the native 5-D command in [-1, 1] (SurRoL's action space and what the
//!   scripted experts emit, [`ActionSpace::Native`]).
//! - Work runs in a rayon pool of `threads` workers (0: one per core), one environment per task.

use super::options::{EvalError, EvalOptions};
use super::run::{trial_env, trial_setup};
use super::shaping::potential;
use crate::env::{Env, EnvObservation, EnvOptions, Images};
use crate::policy::{ExpertLibrary, ExpertPolicy, Policy};
use crate::sim::{NativeCommand, PhysicalAction};
use crate::task::TaskId;
use rayon::prelude::*;

/// What an environment's actions are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ActionSpace {
    /// `[dx, dy, dz (m), droll, dpitch, dyaw (rad), gripper (1 open, 0 closed)]`, clipped to
    /// 1 cm, no tilt and 30 deg a step.
    #[default]
    Dataset,
    /// `[dx, dy, dz, dyaw, jaw]` in [-1, 1]: 1 cm and 30 deg at full scale, jaw < 0 closes.
    Native,
}

impl ActionSpace {
    /// Values per action.
    pub fn dims(self) -> usize {
        match self {
            ActionSpace::Dataset => 7,
            ActionSpace::Native => 5,
        }
    }
}

/// The reward of a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Reward {
    /// 1 on the step that reaches success, else 0.
    #[default]
    Sparse,
    /// The sparse reward plus potential-based shaping over the task's stages
    /// ([`super::shaping`]).
    Dense,
}

/// How a [`VectorEnv`] is set up.
#[derive(Clone, Debug, PartialEq)]
pub struct VectorOptions {
    pub task: TaskId,
    pub num_envs: usize,
    /// Scenes, instructions, seed and camera as `surgvla eval` draws them.
    pub eval: EvalOptions,
    /// Render the endoscope image (and depth and mask) into every observation.
    pub render: bool,
    pub actions: ActionSpace,
    pub reward: Reward,
    /// Step limit (None: the task's).
    pub max_steps: Option<u32>,
    /// Worker threads (0: one per core).
    pub threads: usize,
    /// The perturbation every trial runs under ([`super::perturb`]; default: none), drawn per
    /// trial as `eval --perturb` draws it.
    pub variant: super::perturb::Variant,
}

/// One environment of the vector.
struct Slot {
    env: Env,
    observation: EnvObservation,
    trial: u32,
    /// Its episode ended: the next step starts the next trial.
    ended: bool,
    potential: f64,
    expert: Option<ExpertPolicy>,
}

/// Observations of every environment, row after row.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Observations {
    /// n x H x W x 3 (empty without rendering).
    pub rgb: Vec<u8>,
    /// n x H x W metres (empty without rendering).
    pub depth_m: Vec<f32>,
    /// n x H x W object ids (empty without rendering).
    pub mask: Vec<u8>,
    /// n x 7.
    pub state: Vec<f32>,
    /// n x 28 object poses.
    pub environment_state: Vec<f32>,
}

/// What one environment's step did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Outcome {
    pub reward: f64,
    /// Success or a failure that cannot be undone (a distractor grasped).
    pub terminated: bool,
    /// The step limit ended the episode.
    pub truncated: bool,
    pub success: bool,
    /// The step started the environment's next trial (its action was ignored).
    pub autoreset: bool,
    /// Steps of the current episode.
    pub steps: u32,
    pub trial: u32,
    /// The scene seed of the trial.
    pub seed: u64,
    /// What held or was missing (the predicate's reason, or the step limit's).
    pub reason: String,
    /// The action had to be changed to fit the action space or the workspace.
    pub clipped: bool,
}

/// `num_envs` environments of one task.
pub struct VectorEnv {
    options: VectorOptions,
    slots: Vec<Slot>,
    pool: rayon::ThreadPool,
    experts: Option<ExpertLibrary>,
}

impl VectorEnv {
    /// The environments at trials 0..num_envs.
    pub fn new(options: VectorOptions) -> Result<VectorEnv, EvalError> {
        if options.num_envs == 0 {
            return Err(EvalError::Options("num_envs must be at least 1".into()));
        }
        let pool = crate::threads::pool(options.threads)
            .map_err(|e| EvalError::Options(crate::error::chain(&e)))?;
        let mut env = VectorEnv {
            slots: Vec::with_capacity(options.num_envs),
            options,
            pool,
            experts: None,
        };
        for trial in 0..env.options.num_envs {
            let slot = env.start(u32::try_from(trial).unwrap_or(u32::MAX), None)?;
            env.slots.push(slot);
        }
        Ok(env)
    }

    pub fn options(&self) -> &VectorOptions {
        &self.options
    }

    pub fn num_envs(&self) -> usize {
        self.options.num_envs
    }

    /// The step limit of an episode.
    pub fn max_steps(&self) -> u32 {
        (self.options.max_steps).unwrap_or_else(|| self.options.task.step_limit())
    }

    /// A fresh environment at `trial` under the vector's variant (the expert re-planned when
    /// one is attached).
    fn start(&self, trial: u32, experts: Option<&ExpertLibrary>) -> Result<Slot, EvalError> {
        let options = &self.options;
        let task = options.task;
        let setup = trial_setup(&options.eval, task, &options.variant, trial)?;
        let seed = setup.instance.seed;
        let env_options = EnvOptions {
            max_steps: options.max_steps,
            ..trial_env(&options.eval, &setup, options.render)
        };
        let (env, observation) = Env::from_instance(setup.instance, &env_options);
        let expert = match experts {
            Some(library) => Some(library.plan(task)?.expert(
                env.instance(),
                &observation.sim,
                seed,
            )?),
            None => None,
        };
        Ok(Slot {
            potential: potential(env.instance(), &observation.sim),
            env,
            observation,
            trial,
            ended: false,
            expert,
        })
    }

    /// The trial after `trial` in this vector's walk.
    fn next_trial(&self, trial: u32) -> u32 {
        trial.saturating_add(u32::try_from(self.options.num_envs).unwrap_or(u32::MAX))
    }

    /// Starts every environment's trial: `trials[i]`, or the one after its current trial.
    pub fn reset(&mut self, trials: &[Option<u32>]) -> Result<Observations, EvalError> {
        if trials.len() != self.slots.len() {
            return Err(EvalError::Options(format!(
                "{} seeds for {} environments",
                trials.len(),
                self.slots.len()
            )));
        }
        let next: Vec<u32> = (self.slots.iter().zip(trials))
            .map(|(slot, t)| t.unwrap_or_else(|| self.next_trial(slot.trial)))
            .collect();
        let experts = self.experts.as_ref();
        let this = &*self;
        let slots = self.pool.install(|| {
            (next.par_iter())
                .map(|&trial| this.start(trial, experts))
                .collect::<Result<Vec<_>, _>>()
        })?;
        self.slots = slots;
        Ok(self.observations())
    }

    /// Steps every environment with its row of `actions` (n x [`ActionSpace::dims`] values);
    /// an environment whose episode had ended starts its next trial instead.
    pub fn step(&mut self, actions: &[f64]) -> Result<(Observations, Vec<Outcome>), EvalError> {
        let dims = self.options.actions.dims();
        if actions.len() != self.slots.len() * dims {
            return Err(EvalError::Options(format!(
                "{} action values for {} environments of {dims}",
                actions.len(),
                self.slots.len()
            )));
        }
        let mut slots = std::mem::take(&mut self.slots);
        let experts = self.experts.as_ref();
        let this = &*self;
        let step = |(slot, action): (&mut Slot, &[f64])| this.step_slot(slot, action, experts);
        // One environment steps on the caller's thread: a hop to the pool and back would cost
        // more than it could save.
        let outcomes = if slots.len() == 1 {
            (slots.iter_mut().zip(actions.chunks_exact(dims)))
                .map(step)
                .collect::<Result<Vec<_>, _>>()
        } else {
            self.pool.install(|| {
                (slots.par_iter_mut().zip(actions.par_chunks_exact(dims)))
                    .map(step)
                    .collect::<Result<Vec<_>, _>>()
            })
        };
        self.slots = slots;
        Ok((self.observations(), outcomes?))
    }

    fn step_slot(
        &self,
        slot: &mut Slot,
        action: &[f64],
        experts: Option<&ExpertLibrary>,
    ) -> Result<Outcome, EvalError> {
        if slot.ended {
            *slot = self.start(self.next_trial(slot.trial), experts)?;
            return Ok(Outcome {
                autoreset: true,
                trial: slot.trial,
                seed: slot.env.instance().seed,
                reason: slot.env.verdict().reason,
                ..Outcome::default()
            });
        }
        if let Some(images) = slot.observation.images.take() {
            slot.env.recycle(images);
        }
        let step = match self.options.actions {
            ActionSpace::Dataset => {
                let values: [f64; 7] = std::array::from_fn(|i| action[i]);
                slot.env.step(&PhysicalAction::from_array(values))
            }
            ActionSpace::Native => {
                let values: [f64; 5] = std::array::from_fn(|i| action[i]);
                slot.env.step_native(&NativeCommand::from_array(values))
            }
        };
        let instance = slot.env.instance();
        let success = step.verdict.success;
        let terminated = success || instance.terminal_failure(&step.observation.sim).is_some();
        let truncated = !terminated && step.done;
        let after = potential(instance, &step.observation.sim);
        let reward = f64::from(u8::from(success))
            + match self.options.reward {
                Reward::Sparse => 0.0,
                Reward::Dense => after - slot.potential,
            };
        let steps = slot.env.steps();
        let reason = if truncated {
            format!("step limit {steps} reached: {}", step.verdict.reason)
        } else {
            step.verdict.reason
        };
        slot.potential = after;
        slot.ended = terminated || truncated;
        slot.observation = step.observation;
        Ok(Outcome {
            reward,
            terminated,
            truncated,
            success,
            autoreset: false,
            steps,
            trial: slot.trial,
            seed: instance.seed,
            reason,
            clipped: step.clipped,
        })
    }

    /// The current observations, row after row.
    fn observations(&self) -> Observations {
        let mut out = Observations::default();
        for slot in &self.slots {
            let o = &slot.observation;
            out.state.extend_from_slice(&o.state);
            out.environment_state
                .extend_from_slice(&o.environment_state);
            if let Some(Images { rgb, depth_m, mask }) = &o.images {
                out.rgb.extend_from_slice(rgb);
                out.depth_m.extend_from_slice(depth_m);
                out.mask.extend_from_slice(mask);
            }
        }
        out
    }

    /// Environment `i`'s endoscope image (H x W x 3), when it renders.
    pub fn frame(&self, i: usize) -> Option<&[u8]> {
        let slot = self.slots.get(i)?;
        slot.observation.images.as_ref().map(|im| im.rgb.as_slice())
    }

    /// Every environment's instruction (what the policy is told).
    pub fn instructions(&self) -> Vec<String> {
        (self.slots.iter())
            .map(|s| s.env.instance().instruction.clone())
            .collect()
    }

    /// Every environment's current trial and scene seed.
    pub fn trials(&self) -> Vec<(u32, u64)> {
        (self.slots.iter())
            .map(|s| (s.trial, s.env.instance().seed))
            .collect()
    }

    /// Gives every environment the task's scripted expert (privileged: it reads the simulator),
    /// planned from the current state and again at every reset.
    pub fn attach_expert(&mut self) -> Result<(), EvalError> {
        let library = ExpertLibrary::builtin()?;
        for slot in &mut self.slots {
            let plan = library.plan(self.options.task)?;
            let seed = slot.env.instance().seed;
            slot.expert = Some(plan.expert(slot.env.instance(), &slot.observation.sim, seed)?);
        }
        self.experts = Some(library);
        Ok(())
    }

    /// The experts' next actions in this vector's action space (n x dims) and whether each
    /// expert has finished its plan (then its row holds still with the jaws as they are).
    /// Empty when no expert is attached.
    pub fn expert_actions(&mut self) -> (Vec<f64>, Vec<bool>) {
        let actions = self.options.actions;
        let mut values = Vec::with_capacity(self.slots.len() * actions.dims());
        let mut done = Vec::with_capacity(self.slots.len());
        for slot in &mut self.slots {
            let Some(expert) = slot.expert.as_mut() else {
                return (Vec::new(), Vec::new());
            };
            let finished = expert.is_done();
            let open = slot.observation.sim.jaw_command == crate::sim::JawCommand::Open;
            let command = if finished {
                NativeCommand {
                    jaw: if open { 1.0 } else { -1.0 },
                    ..NativeCommand::default()
                }
            } else {
                expert.act(&slot.observation.sim)
            };
            values.extend(match actions {
                ActionSpace::Native => command.to_array().to_vec(),
                ActionSpace::Dataset => dataset_action(&command).to_vec(),
            });
            done.push(finished);
        }
        (values, done)
    }
}

/// The dataset action a native command asks for: its deltas at full scale, no tilt, the gripper
/// open (1) or closed (0).
pub fn dataset_action(command: &NativeCommand) -> [f64; 7] {
    use crate::sim::control::{NATIVE_POSITION_SCALE_M, NATIVE_YAW_SCALE_RAD};
    let unit = |v: f64| v.clamp(-1.0, 1.0);
    let open = command.jaw_command() == crate::sim::JawCommand::Open;
    [
        unit(command.dx) * NATIVE_POSITION_SCALE_M,
        unit(command.dy) * NATIVE_POSITION_SCALE_M,
        unit(command.dz) * NATIVE_POSITION_SCALE_M,
        0.0,
        0.0,
        unit(command.dyaw) * NATIVE_YAW_SCALE_RAD,
        if open { 1.0 } else { 0.0 },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{PolicyChoice, evaluate};

    fn options(task: TaskId, num_envs: usize, actions: ActionSpace) -> VectorOptions {
        VectorOptions {
            task,
            num_envs,
            eval: EvalOptions::default(),
            render: false,
            actions,
            reward: Reward::Sparse,
            max_steps: None,
            threads: 2,
            variant: Default::default(),
        }
    }

    #[test]
    fn seeds_are_evals_trials_and_the_autoreset_walks_on() {
        let mut env = VectorEnv::new(VectorOptions {
            max_steps: Some(2),
            ..options(TaskId::NeedlePick, 2, ActionSpace::Dataset)
        })
        .expect("envs");
        let seed = |trial| crate::eval::trial_seed(0, TaskId::NeedlePick, trial);
        assert_eq!(env.trials(), vec![(0, seed(0)), (1, seed(1))]);
        env.reset(&[Some(5), None]).expect("reset");
        assert_eq!(env.trials(), vec![(5, seed(5)), (3, seed(3))]);
        let hold = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0].repeat(2);
        let (_, first) = env.step(&hold).expect("step");
        assert!(first.iter().all(|o| !o.truncated && o.steps == 1));
        let (_, second) = env.step(&hold).expect("step");
        assert!(
            second
                .iter()
                .all(|o| o.truncated && !o.terminated && !o.success)
        );
        assert!(second[0].reason.starts_with("step limit 2 reached"));
        let (observations, third) = env.step(&hold).expect("step");
        assert!(
            third
                .iter()
                .all(|o| o.autoreset && o.steps == 0 && o.reward == 0.0)
        );
        assert_eq!(env.trials(), vec![(7, seed(7)), (5, seed(5))]);
        assert_eq!((observations.state.len(), observations.rgb.len()), (14, 0));
        assert!(
            env.step(&hold[..7]).is_err(),
            "one row for two environments"
        );
    }

    /// The expert stepped through the vector env (native commands) plays `eval --policy
    /// expert`'s trials: same successes, same step counts.
    #[test]
    fn the_expert_through_the_vector_env_scores_as_eval_does() {
        let task = TaskId::GauzePickDistractors;
        let trials = 3;
        let out = std::env::temp_dir().join(format!("surgvla-vector-{}", std::process::id()));
        let eval = EvalOptions {
            tasks: vec![task],
            trials,
            recordings_per_task: 0,
            out: out.clone(),
            ..EvalOptions::default()
        };
        let report = evaluate(&PolicyChoice::Expert, &eval, &|_, _| {}).expect("eval");
        let _ = std::fs::remove_dir_all(&out);
        let mut env =
            VectorEnv::new(options(task, trials as usize, ActionSpace::Native)).expect("envs");
        env.attach_expert().expect("expert");
        let mut results: Vec<Option<(bool, u32)>> = vec![None; trials as usize];
        let mut steps = 0;
        while results.iter().any(Option::is_none) {
            let (actions, done) = env.expert_actions();
            for (i, _) in done.iter().enumerate().filter(|(_, d)| **d) {
                results[i].get_or_insert((false, steps));
            }
            let (_, outcomes) = env.step(&actions).expect("step");
            steps += 1;
            for (i, o) in outcomes.iter().enumerate() {
                if o.terminated || o.truncated {
                    results[i].get_or_insert((o.success, o.steps));
                }
            }
        }
        let expected: Vec<Option<(bool, u32)>> = (report.trials.iter())
            .map(|t| Some((t.success, t.steps)))
            .collect();
        assert_eq!(results, expected);
        assert!(results.iter().flatten().any(|r| r.0), "the expert succeeds");
    }
}
