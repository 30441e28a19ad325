//! The command line's error: a library error (or a usage mistake found after parsing) with its
//! [`ErrorKind`], which decides the exit code, and the chain printed once.

use surgvla::error::{ErrorKind, HasKind};
use surgvla::export::ExportError;

/// An error on its way to `main`: what happened, whose mistake it is, and a hint for the user.
#[derive(Debug)]
pub(crate) struct CliError {
    pub kind: ErrorKind,
    pub error: anyhow::Error,
    /// Said after the error (e.g. how to continue after a full disk).
    pub hint: Option<&'static str>,
    /// Output piped into a reader that stopped (`surgvla tasks | head`): not an error.
    pub quiet: bool,
}

/// The hint after a full disk.
const DISK_FULL: &str = "the disk is full: free space and run the command again";
/// The hint after a failure that left a resumable dataset.
const RESUME: &str = "the dataset is incomplete: run the same command with --resume to \
     continue it from its last checkpoint";
/// The hint when the output folder holds an interrupted dataset.
const INTERRUPTED: &str = "add --resume (with the options it was started with) to continue it, \
     or choose an empty or new directory";
/// The hint for an RLDS dataset another tool wrote.
const NO_FRAME_RATE: &str = "give its frame rate with --fps";
/// The hint for clouds of a dataset without a workspace.
const NO_CROP_BOX: &str = "give the crop box with --crop";
/// The same after a full disk.
const DISK_FULL_RESUME: &str = "the disk is full: free space, then run the same command with \
     --resume to continue the dataset from its last checkpoint";

impl CliError {
    fn new(kind: ErrorKind, error: impl Into<anyhow::Error>) -> Self {
        CliError {
            kind,
            error: error.into(),
            hint: None,
            quiet: false,
        }
    }

    /// A mistake in what the user gave, found after parsing (exit 2).
    pub(crate) fn usage(message: impl std::fmt::Display) -> Self {
        CliError::new(ErrorKind::Usage, anyhow::anyhow!("{message}"))
    }

    /// The work found the data invalid (exit 1).
    pub(crate) fn invalid(message: impl std::fmt::Display) -> Self {
        CliError::new(ErrorKind::Failed, anyhow::anyhow!("{message}"))
    }

    /// Says how to continue when the failure left a dataset that `--resume` continues (and
    /// only then).
    pub(crate) fn resumable(mut self, resumable: bool) -> Self {
        if resumable && self.kind == ErrorKind::Failed {
            self.hint = Some(if self.hint == Some(DISK_FULL) {
                DISK_FULL_RESUME
            } else {
                RESUME
            });
        }
        self
    }

    /// Adds what the command was doing, keeping the kind.
    pub(crate) fn context(mut self, what: impl std::fmt::Display + Send + Sync + 'static) -> Self {
        self.error = self.error.context(what);
        self
    }

    /// The error and its causes on one line, each said once, then the hint.
    pub(crate) fn message(&self) -> String {
        let causes: Vec<String> = self.error.chain().map(|c| c.to_string()).collect();
        let mut message = causes.join(": ");
        if let Some(hint) = self.hint {
            message.push('\n');
            message.push_str(hint);
        }
        message
    }
}

/// Every library error, the same way: its kind decides the exit code, and a full disk or a
/// dataset the user can continue gets a hint saying what to do.
impl<E: HasKind> From<E> for CliError {
    fn from(error: E) -> Self {
        // A bare I/O error reaching the CLI is a failed write of its output (`say!`, the
        // tables): the library's file errors carry their path in their own types.
        if let Some(io) = (&error as &dyn std::error::Error).downcast_ref::<std::io::Error>() {
            let quiet = io.kind() == std::io::ErrorKind::BrokenPipe;
            let mut cli =
                CliError::new(ErrorKind::Failed, error).context("writing to standard output");
            cli.quiet = quiet;
            return cli;
        }
        let hint = if error.is_disk_full() {
            Some(DISK_FULL)
        } else {
            hint_for(&error)
        };
        let mut cli = CliError::new(error.kind(), error);
        cli.hint = hint;
        cli
    }
}

/// The hint for what the library's error says in data: an interrupted dataset in the way, an
/// RLDS dataset without a frame rate.
fn hint_for(error: &(dyn std::error::Error + 'static)) -> Option<&'static str> {
    let mut next = Some(error);
    while let Some(error) = next {
        match error.downcast_ref::<ExportError>() {
            Some(ExportError::NotEmpty {
                interrupted: true, ..
            }) => return Some(INTERRUPTED),
            Some(ExportError::NoFrameRate { .. }) => return Some(NO_FRAME_RATE),
            Some(ExportError::NoCropBox) => return Some(NO_CROP_BOX),
            _ => next = error.source(),
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Error, ErrorKind as Io};

    #[test]
    fn a_full_disk_names_the_file_once_and_says_what_to_do() {
        let error = CliError::from(ExportError::Io {
            path: "out/data/chunk-000/file-000.parquet".into(),
            source: Error::from(Io::StorageFull),
        });
        let message = error.message();
        let first_line = message.lines().next().unwrap();
        assert!(
            first_line.starts_with("out/data/chunk-000/file-000.parquet: "),
            "{message}"
        );
        let said = Error::from(Io::StorageFull).to_string();
        assert_eq!(first_line.matches(&said).count(), 1, "{message}");
        assert!(message.contains("the disk is full"), "{message}");
        assert_eq!(error.kind.exit_code(), 1);
    }

    #[test]
    fn context_and_causes_are_all_said_and_kinds_decide_exit_codes() {
        let error = CliError::from(surgvla::policy::PlanError::Io {
            path: "plans/gauze_pick.toml".into(),
            source: Error::new(Io::NotFound, "no such file"),
        })
        .context("loading the expert plans");
        assert_eq!(
            error.message(),
            "loading the expert plans: reading plans/gauze_pick.toml: no such file"
        );
        assert_eq!(error.kind.exit_code(), 2);
        let not_empty = CliError::from(ExportError::NotEmpty {
            path: "out".into(),
            interrupted: true,
        });
        assert_eq!(not_empty.kind.exit_code(), 2);
        assert!(
            not_empty.message().contains("add --resume"),
            "{}",
            not_empty.message()
        );
        assert!(CliError::from(Error::from(Io::BrokenPipe)).quiet);
    }
}
