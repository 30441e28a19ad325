//! `surgvla._native`: the compiled half of the `surgvla` Python package.
//!
//! - [`cli`]: the `surgvla` command (the console script pip installs), the binary's own
//!   [`app::run`] over the same modules (`src/bin/`), so its behaviour, exit codes and bytes are
//!   the binary's.
//! - [`vector::VectorCore`]: `surgvla::eval::vector::VectorEnv` for Python, observations as numpy
//!   arrays that own the Rust buffers, every step with the GIL released. The gymnasium classes
//!   over it are Python (`python/surgvla/`).
//! - [`tasks`]: the eight tasks' ids, names, step limits and instructions.
//!
//! The CLI's modules are compiled here from their files in `src/bin/` (this crate's root stands
//! in for `src/bin/surgvla.rs`, so their `crate::` paths resolve the same way).

#[macro_use]
#[path = "../../src/bin/say.rs"]
mod say;

#[path = "../../src/bin/app.rs"]
mod app;
#[path = "../../src/bin/commands/mod.rs"]
mod commands;
#[path = "../../src/bin/error.rs"]
mod error;
#[path = "../../src/bin/formats.rs"]
mod formats;
#[path = "../../src/bin/interrupt.rs"]
mod interrupt;
#[path = "../../src/bin/job.rs"]
mod job;
#[path = "../../src/bin/memory.rs"]
mod memory;
#[path = "../../src/bin/progress.rs"]
mod progress;

mod vector;

use pyo3::prelude::*;
use pyo3::types::PyDict;
use surgvla::task::TaskId;

/// Runs the `surgvla` command line (`argv[0]` is the program name) and returns its exit code.
/// Python's own SIGINT handler stays unless the caller asks for the command's
/// ([`catch_interrupts`], as the console script does).
#[pyfunction]
fn cli(py: Python<'_>, argv: Vec<String>) -> u8 {
    py.detach(|| app::run(argv.into_iter().map(std::ffi::OsString::from)))
}

/// Ctrl-C and SIGTERM handled as the binary handles them: the command says what it kept and
/// the process exits 130 (the console script, a process that only runs the command, calls it).
#[pyfunction]
fn catch_interrupts() {
    interrupt::install();
}

/// The tasks in benchmark order: dicts of `id` ("T1-1"), `name` ("gauze_pick"), `level`,
/// `max_steps`, `instruction` and `paraphrases`.
#[pyfunction]
fn tasks(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    TaskId::ALL
        .iter()
        .map(|task| {
            let d = PyDict::new(py);
            d.set_item("id", task.code())?;
            d.set_item("name", task.name())?;
            d.set_item("level", task.level())?;
            d.set_item("max_steps", task.step_limit())?;
            d.set_item("instruction", task.instruction())?;
            d.set_item("paraphrases", task.paraphrases().to_vec())?;
            Ok(d)
        })
        .collect()
}

/// The perturbation suites `surgvla eval --suite` runs: {suite name: [variant, ...]}, each
/// variant a `perturb=` value of the environments ("none" first).
#[pyfunction]
fn suites(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    for (name, _) in surgvla::eval::perturb::SUITE_FILES {
        let suite = surgvla::eval::perturb::Suite::builtin(name)
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        let variants: Vec<String> = suite.variants.iter().map(|v| v.name()).collect();
        d.set_item(name, variants)?;
    }
    Ok(d)
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(cli, m)?)?;
    m.add_function(wrap_pyfunction!(catch_interrupts, m)?)?;
    m.add_function(wrap_pyfunction!(tasks, m)?)?;
    m.add_function(wrap_pyfunction!(suites, m)?)?;
    m.add_class::<vector::VectorCore>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The success rules the environments judge by (what datasets record as `success_rules`).
    m.add("RULE_SET", surgvla::task::success::RULE_SET)?;
    Ok(())
}
