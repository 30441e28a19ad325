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
