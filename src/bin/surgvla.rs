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
    on_interrupt();
    std::process::ExitCode::from(app::run(std::env::args_os()))
}

/// Ctrl-C and SIGTERM: say what the interruption leaves ([`interrupt::message`]) and exit 130.
/// What was being written stays as an interrupted run's folder (marker and checkpoint), which
/// `--resume` continues, as after any other stop.
fn on_interrupt() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            let name = if signal == SIGINT {
                "Ctrl-C"
            } else {
                "SIGTERM"
            };
            eprintln!("\n{}", interrupt::message(name));
            std::process::exit(130);
        }
    });
}
