//! What kind of failure an error is, so the command line can map every library error to its
//! exit code without inspecting messages: [`ErrorKind::Usage`] (exit 2, the command could not
//! start because of what the user gave) or [`ErrorKind::Failed`] (exit 1, the work failed or the
//! data is invalid).

/// Whose mistake an error is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// What the user gave cannot be used: a bad value, an unknown task, an output path that is
    /// a file or not writable, an unusable policy file, a folder that cannot be resumed.
    Usage,
    /// The work failed (I/O, a full disk, no verified episode) or the data is invalid.
    Failed,
}

impl ErrorKind {
    /// The process exit code of this kind: 2 or 1.
    pub fn exit_code(self) -> u8 {
        match self {
            ErrorKind::Usage => 2,
            ErrorKind::Failed => 1,
        }
    }
}

/// A library error the command line can classify: its [`ErrorKind`] (the exit code) and
/// whether it is a full disk (the command line then says how to go on). Every library error
/// type implements it, and the command line converts any of them the same way.
pub trait HasKind: std::error::Error + Send + Sync + 'static {
    /// Whose mistake it is.
    fn kind(&self) -> ErrorKind;
    /// Whether the disk (or quota) is full.
    fn is_disk_full(&self) -> bool {
        false
    }
}

/// JSON the command line serialises itself (a report) cannot fail on the user's input.
impl HasKind for serde_json::Error {
    fn kind(&self) -> ErrorKind {
        ErrorKind::Failed
    }
}

/// A bare I/O error (the command line writing its own output): the work failed.
impl HasKind for std::io::Error {
    fn kind(&self) -> ErrorKind {
        ErrorKind::Failed
    }

    fn is_disk_full(&self) -> bool {
        self.kind() == std::io::ErrorKind::StorageFull
    }
}

/// An error and its sources on one line, `: `-separated (for messages that embed an error,
/// such as a validate finding or a policy's reply).
pub fn chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(inner) = source {
        text.push_str(": ");
        text.push_str(&inner.to_string());
        source = inner.source();
    }
    text
}
