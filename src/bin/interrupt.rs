//! What an interruption (Ctrl-C, SIGTERM) leaves: a command that writes a dataset names it
//! here ([`writing`]) before its long work, and the handler ([`install`]: a thread waiting on
//! the signals, started by the binary's `main` and by the Python module's console script)
//! prints [`message`] once and exits 130, the README's code for it.

use std::path::Path;
use std::sync::Mutex;

/// What the command in progress is writing, said on an interruption.
static WRITING: Mutex<Option<String>> = Mutex::new(None);

/// Says that the command is now writing `out`; `resumable`: the same command with `--resume`
/// continues it from its last checkpoint.
pub(crate) fn writing(out: &Path, resumable: bool) {
    let text = if resumable {
        format!(
            "{} keeps what was written up to its last checkpoint; run the same command with --resume to continue it",
            out.display()
        )
    } else {
        format!(
            "{} is unfinished; run the same command again to write it",
            out.display()
        )
    };
    *WRITING.lock().unwrap_or_else(|e| e.into_inner()) = Some(text);
}

/// The line an interruption prints (`signal`: its name).
pub(crate) fn message(signal: &str) -> String {
    match WRITING.lock().unwrap_or_else(|e| e.into_inner()).as_deref() {
        Some(writing) => format!("interrupted ({signal}): {writing}"),
        None => format!("interrupted ({signal})"),
    }
}

/// Ctrl-C and SIGTERM: say what the interruption leaves ([`message`]) and exit 130. What was
/// being written stays as an interrupted run's folder (marker and checkpoint), which
/// `--resume` continues, as after any other stop.
pub(crate) fn install() {
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
            eprintln!("\n{}", message(name));
            std::process::exit(130);
        }
    });
}
