//! The trials an evaluation has scored so far, kept in its results folder
//! (`.eval-journal.jsonl`) so that `eval --resume` continues an interrupted run from them
//! rather than from the start, to the bytes an uninterrupted run writes (every trial is a pure
//! function of its seed; a served policy's, of the policy).
//!
//! The first line names the run (what shapes its results: the policy, the options, the
//! suite); each further line is one trial's result, in the order trials finished. A built-in
//! policy's trials of a task are journaled together once the task's failures are recorded; a
//! served policy's one by one. A line cut short by the interruption is dropped on resume.

use super::options::EvalError;
use super::results::TrialResult;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The journal's name in the results folder.
pub(super) const JOURNAL: &str = ".eval-journal.jsonl";
/// The largest journal read back (a trial's line is about a kilobyte).
const MAX_JOURNAL_BYTES: u64 = 256 << 20;

/// An evaluation's journal, open for appending.
pub(super) struct Journal {
    path: PathBuf,
    file: std::fs::File,
    /// Trials read back, by (variant, task id), in trial order.
    done: BTreeMap<(String, String), Vec<TrialResult>>,
}

fn problem(path: &Path, what: impl std::fmt::Display) -> EvalError {
    EvalError::Options(format!(
        "{}: {what}; give --replace to start the evaluation over",
        path.display()
    ))
}

fn write_error(path: &Path) -> impl Fn(std::io::Error) -> EvalError + '_ {
    move |e| EvalError::Write {
        path: path.to_path_buf(),
        source: crate::export::ExportError::io(path)(e),
    }
}

/// How many trials a journal in `out` holds (None: there is none): what an interrupted run
/// left, said when it is found without `--resume`.
pub(super) fn scored(out: &Path) -> Option<usize> {
    let bytes = crate::export::bounded::read_capped(&out.join(JOURNAL), MAX_JOURNAL_BYTES).ok()?;
    let lines = bytes.iter().filter(|b| **b == b'\n').count();
    Some(lines.saturating_sub(1))
}

impl Journal {
    /// A new journal in `out` for the run named `identity` (an earlier one replaced).
    pub(super) fn create(out: &Path, identity: &serde_json::Value) -> Result<Journal, EvalError> {
        let path = out.join(JOURNAL);
        let mut file = std::fs::File::create(&path).map_err(write_error(&path))?;
        writeln!(file, "{identity}").map_err(write_error(&path))?;
        Ok(Journal {
            path,
            file,
            done: BTreeMap::new(),
        })
    }

    /// The journal in `out` read back, for a resumed run named `identity`: refused when it
    /// names another run or a line is not a trial's result.
    pub(super) fn resume(out: &Path, identity: &serde_json::Value) -> Result<Journal, EvalError> {
        let path = out.join(JOURNAL);
        let bytes = crate::export::bounded::read_capped(&path, MAX_JOURNAL_BYTES)
            .map_err(|e| problem(&path, crate::error::chain(&e)))?;
        // A line the interruption cut short (no newline after it) is dropped.
        let whole = bytes.iter().rposition(|b| *b == b'\n').map_or(0, |i| i + 1);
        let mut lines = bytes[..whole]
            .split(|b| *b == b'\n')
            .filter(|l| !l.is_empty());
        let first: serde_json::Value = (lines.next())
            .and_then(|l| serde_json::from_slice(l).ok())
            .ok_or_else(|| problem(&path, "not an evaluation's journal"))?;
        if first != *identity {
            return Err(problem(
                &path,
                "the journal is another evaluation's (its policy or options differ from this command's)",
            ));
        }
        let mut done: BTreeMap<(String, String), Vec<TrialResult>> = BTreeMap::new();
        for (n, line) in lines.enumerate() {
            let trial: TrialResult = serde_json::from_slice(line)
                .map_err(|e| problem(&path, format!("line {}: {e}", n + 2)))?;
            done.entry((trial.variant.clone(), trial.task_id.clone()))
                .or_default()
                .push(trial);
        }
        for trials in done.values_mut() {
            trials.sort_by_key(|t| t.trial);
            trials.dedup_by_key(|t| t.trial);
        }
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .map_err(write_error(&path))?;
        file.set_len(whole as u64).map_err(write_error(&path))?;
        std::io::Seek::seek(&mut file, std::io::SeekFrom::End(0)).map_err(write_error(&path))?;
        Ok(Journal { path, file, done })
    }

    /// The trials of `task` under `variant` scored before, in trial order.
    pub(super) fn done(&self, variant: &str, task: &str) -> &[TrialResult] {
        (self.done.get(&(variant.to_string(), task.to_string()))).map_or(&[], Vec::as_slice)
    }

    /// Every trial scored before.
    pub(super) fn count(&self) -> usize {
        self.done.values().map(Vec::len).sum()
    }

    /// Appends scored trials.
    pub(super) fn record(&mut self, trials: &[TrialResult]) -> Result<(), EvalError> {
        let mut text = String::new();
        for trial in trials {
            let line = serde_json::to_string(trial).map_err(|e| EvalError::Write {
                path: self.path.clone(),
                source: crate::export::ExportError::Json {
                    path: self.path.clone(),
                    source: e,
                },
            })?;
            text.push_str(&line);
            text.push('\n');
        }
        let error = write_error(&self.path);
        self.file.write_all(text.as_bytes()).map_err(&error)?;
        self.file.flush().map_err(error)
    }
}
