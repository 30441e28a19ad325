//! What an interruption (Ctrl-C, SIGTERM) leaves: a command that writes a dataset names it
//! here ([`writing`]) before its long work, and the binary's handler (`surgvla.rs`, a thread
//! waiting on the signals) prints [`message`] once and exits 130, the README's code for it.
//! The Python module's console script installs no handler: Python keeps its own.

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
// The binary's handler reads it; the Python module compiles this file too and installs none.
#[allow(dead_code)]
pub(crate) fn message(signal: &str) -> String {
    match WRITING.lock().unwrap_or_else(|e| e.into_inner()).as_deref() {
        Some(writing) => format!("interrupted ({signal}): {writing}"),
        None => format!("interrupted ({signal})"),
    }
}
