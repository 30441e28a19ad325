//! [`VectorCore`]: `surgvla::eval::vector::VectorEnv` as a Python class. Every reset and step
//! runs with the GIL released; what comes back is a few numpy arrays that own the Rust buffers
//! (no per-environment Python work beyond one string per environment for the reasons).

use numpy::{AllowTypeChange, PyArray1, PyArrayLike2, PyArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use surgvla::eval::EvalOptions;
use surgvla::eval::vector::{ActionSpace, Observations, Outcome, Reward, VectorEnv, VectorOptions};
use surgvla::task::{InstructionChoice, TaskId};

/// `num_envs` environments of one task (the gymnasium classes in `surgvla/envs.py` wrap it).
#[pyclass(module = "surgvla._native")]
pub(crate) struct VectorCore {
    env: VectorEnv,
    /// Which observation arrays to hand out: (depth, mask).
    images: (bool, bool),
}

/// An error of the library as a Python exception: the user's mistakes as ValueError.
fn to_py(error: &surgvla::eval::EvalError) -> PyErr {
    use surgvla::error::{ErrorKind, HasKind as _};
    let text = surgvla::error::chain(error);
    match error.kind() {
        ErrorKind::Usage => PyValueError::new_err(text),
        _ => PyRuntimeError::new_err(text),
    }
}

fn task_of(name: &str) -> PyResult<TaskId> {
    name.parse()
        .map_err(|e| PyValueError::new_err(format!("{e} (see surgvla.tasks())")))
}

fn choice<T: Copy>(name: &str, what: &str, options: &[(&str, T)]) -> PyResult<T> {
    (options.iter().find(|(n, _)| *n == name))
        .map(|(_, v)| *v)
        .ok_or_else(|| {
            let names: Vec<&str> = options.iter().map(|(n, _)| *n).collect();
            PyValueError::new_err(format!("{what} {name:?}: one of {names:?}"))
        })
}

#[pymethods]
impl VectorCore {
    #[new]
    #[pyo3(signature = (task, num_envs, *, render, depth, mask, actions, reward, instructions,
        seed, distractors, spawn_scale, max_steps, threads, perturb))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        task: &str,
        num_envs: usize,
        render: bool,
        depth: bool,
        mask: bool,
        actions: &str,
        reward: &str,
        instructions: &str,
        seed: u64,
        distractors: usize,
        spawn_scale: Option<f64>,
        max_steps: Option<u32>,
        threads: usize,
        perturb: &str,
    ) -> PyResult<Self> {
        let dimensions = surgvla::eval::perturb::Dimensions::v1();
        let variant = surgvla::eval::perturb::Variant::parse(perturb, dimensions)
            .map_err(|e| PyValueError::new_err(format!("perturb: {e}")))?;
        let task = task_of(task)?;
        let actions = choice(
            actions,
            "action space",
            &[
                ("dataset", ActionSpace::Dataset),
                ("native", ActionSpace::Native),
            ],
        )?;
        let reward = choice(
            reward,
            "reward",
            &[("sparse", Reward::Sparse), ("dense", Reward::Dense)],
        )?;
        let instruction = choice(
            instructions,
            "instructions",
            &[
                ("canonical", InstructionChoice::Canonical),
                ("paraphrase", InstructionChoice::Paraphrase),
                ("mixed", InstructionChoice::Mixed),
                ("detailed", InstructionChoice::Detailed),
                ("absent_object", InstructionChoice::AbsentObject),
            ],
        )?;
        if !(1..=surgvla::task::spawn::MAX_DISTRACTORS).contains(&distractors) {
            let max = surgvla::task::spawn::MAX_DISTRACTORS;
            return Err(PyValueError::new_err(format!("distractors: 1 to {max}")));
        }
        let threads =
            crate::app::threads_arg(&threads.to_string()).map_err(PyValueError::new_err)?;
        let options = VectorOptions {
            task,
            num_envs,
            eval: EvalOptions {
                tasks: vec![task],
                seed,
                instruction,
                distractors,
                spawn_scale,
                ..EvalOptions::default()
            },
            render,
            actions,
            reward,
            max_steps,
            threads,
            variant,
        };
        let env = py.detach(|| VectorEnv::new(options).map_err(|e| to_py(&e)))?;
        Ok(VectorCore {
            env,
            images: (depth, mask),
        })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.env.num_envs()
    }

    #[getter]
    fn max_steps(&self) -> u32 {
        self.env.max_steps()
    }

    #[getter]
    fn task_id(&self) -> &'static str {
        self.env.options().task.code()
    }

    /// (height, width) of the endoscope images.
    #[getter]
    fn image_size(&self) -> (u32, u32) {
        let camera = &self.env.options().eval.camera;
        (camera.height_px, camera.width_px)
    }

    /// Starts every environment's trial (`trials[i]`, or None: the one after its current
    /// trial) and returns the observation arrays.
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        trials: Vec<Option<u32>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let env = &mut self.env;
        let observations = py.detach(|| env.reset(&trials).map_err(|e| to_py(&e)))?;
        self.arrays(py, observations)
    }

    /// Steps every environment with its row of `actions` (n x 7 or n x 5); returns
    /// (observation arrays, outcome arrays, reasons).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: PyArrayLike2<'py, f64, AllowTypeChange>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>, Vec<String>)> {
        let values: Vec<f64> = actions.as_array().iter().copied().collect();
        let env = &mut self.env;
        let (observations, outcomes) = py.detach(|| env.step(&values).map_err(|e| to_py(&e)))?;
        let arrays = self.arrays(py, observations)?;
        let (outcome, reasons) = outcome_arrays(py, outcomes)?;
        Ok((arrays, outcome, reasons))
    }

    /// Every environment's instruction.
    fn instructions(&self) -> Vec<String> {
        self.env.instructions()
    }

    /// Every environment's (trial, scene seed).
    fn trials(&self) -> Vec<(u32, u64)> {
        self.env.trials()
    }

    /// Environment `i`'s endoscope image as H x W x 3 uint8 (None without rendering).
    fn frame<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyAny>>> {
        let (h, w) = self.image_size();
        let Some(rgb) = self.env.frame(i) else {
            return Ok(None);
        };
        let array = PyArray1::from_slice(py, rgb).reshape([h as usize, w as usize, 3])?;
        Ok(Some(array.into_any()))
    }

    /// Gives every environment the task's scripted expert (see `surgvla.expert`).
    fn attach_expert(&mut self, py: Python<'_>) -> PyResult<()> {
        let env = &mut self.env;
        py.detach(|| env.attach_expert().map_err(|e| to_py(&e)))
    }

    /// The experts' next actions (n x dims, float64) and which have finished their plans.
    fn expert_actions<'py>(
        &mut self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let env = &mut self.env;
        let (values, done) = py.detach(|| env.expert_actions());
        if done.is_empty() {
            return Err(PyRuntimeError::new_err("no expert is attached"));
        }
        let dims = self.env.options().actions.dims();
        let actions = PyArray1::from_vec(py, values).reshape([done.len(), dims])?;
        Ok((actions.into_any(), PyArray1::from_vec(py, done).into_any()))
    }
}

impl VectorCore {
    /// The observation arrays: `agent_pos` (n, 7) and `environment_state` (n, 28) float32,
    /// and when rendering `pixels` (n, H, W, 3) uint8, `depth` (n, H, W) float32 metres and
    /// `mask` (n, H, W) uint8 as asked.
    fn arrays<'py>(&self, py: Python<'py>, o: Observations) -> PyResult<Bound<'py, PyDict>> {
        let n = self.env.num_envs();
        let (h, w) = self.image_size();
        let (h, w) = (h as usize, w as usize);
        let d = PyDict::new(py);
        d.set_item(
            "agent_pos",
            PyArray1::from_vec(py, o.state).reshape([n, 7])?,
        )?;
        let poses = o.environment_state.len() / n.max(1);
        let state = PyArray1::from_vec(py, o.environment_state).reshape([n, poses])?;
        d.set_item("environment_state", state)?;
        if !o.rgb.is_empty() {
            d.set_item(
                "pixels",
                PyArray1::from_vec(py, o.rgb).reshape([n, h, w, 3])?,
            )?;
            if self.images.0 {
                d.set_item(
                    "depth",
                    PyArray1::from_vec(py, o.depth_m).reshape([n, h, w])?,
                )?;
            }
            if self.images.1 {
                d.set_item("mask", PyArray1::from_vec(py, o.mask).reshape([n, h, w])?)?;
            }
        }
        Ok(d)
    }
}

/// The outcome arrays (`reward`, `terminated`, `truncated`, `is_success`, `autoreset`,
/// `steps`, `trial`, `seed`, `clipped`) and the reasons.
fn outcome_arrays(
    py: Python<'_>,
    outcomes: Vec<Outcome>,
) -> PyResult<(Bound<'_, PyDict>, Vec<String>)> {
    let d = PyDict::new(py);
    let column = |f: fn(&Outcome) -> bool| outcomes.iter().map(f).collect::<Vec<bool>>();
    d.set_item(
        "reward",
        PyArray1::from_vec(py, outcomes.iter().map(|o| o.reward).collect()),
    )?;
    for (name, f) in [
        ("terminated", (|o| o.terminated) as fn(&Outcome) -> bool),
        ("truncated", |o| o.truncated),
        ("is_success", |o| o.success),
        ("autoreset", |o| o.autoreset),
        ("clipped", |o| o.clipped),
    ] {
        d.set_item(name, PyArray1::from_vec(py, column(f)))?;
    }
    let steps: Vec<u32> = outcomes.iter().map(|o| o.steps).collect();
    d.set_item("steps", PyArray1::from_vec(py, steps))?;
    let trials: Vec<u32> = outcomes.iter().map(|o| o.trial).collect();
    d.set_item("trial", PyArray1::from_vec(py, trials))?;
    let seeds: Vec<u64> = outcomes.iter().map(|o| o.seed).collect();
    d.set_item("seed", PyArray1::from_vec(py, seeds))?;
    Ok((d, outcomes.into_iter().map(|o| o.reason).collect()))
}
