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
