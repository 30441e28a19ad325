//! The `surgvla` command line: [`app::run`] over the process's arguments. The Python module's
//! console script runs the same [`app::run`] (the `python/` crate includes these modules).

#[macro_use]
mod say;

mod app;
mod commands;
mod error;
mod formats;
mod interrupt;
mod job;
mod memory;
mod progress;

fn main() -> std::process::ExitCode {
    interrupt::install();
    std::process::ExitCode::from(app::run(std::env::args_os()))
}
