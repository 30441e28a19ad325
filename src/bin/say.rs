//! `say!`: a line to stdout whose failed write (a closed pipe) returns an error with `?`, which
//! the command line treats as a quiet exit. Declared first, so every command module sees it.

/// Writes a line to stdout; a failed write (a closed pipe) returns an error with `?`, which
/// `main` treats as a quiet exit when the pipe was closed.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($arg)*)?
    }};
}

/// `count` and `noun`, plural unless the count is one: "1 episode", "2 episodes".
pub(crate) fn n(count: impl Into<u64>, noun: &str) -> String {
    match count.into() {
        1 => format!("1 {noun}"),
        count => format!("{count} {noun}s"),
    }
}
