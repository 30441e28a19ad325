//! The one owner of a dataset folder, for every format.
//!
//! - **Lock.** A run holds an advisory lock (`flock`) on the folder for its whole life; the kernel
//!   releases it when the process exits or dies. A second run into the same folder is refused
//!   ([`ExportError::Locked`]) and changes nothing.
//! - **Marker.** [`DatasetDir::create`] refuses a folder that holds anything and writes
//!   [`INCOMPLETE_MARKER`] first; [`DatasetDir::complete`] removes it last, after the format
//!   wrote its last file and the manifest. A dataset with the marker is never complete. The
//!   marker records the run's byte-changing [`RunOptions`] and, once one was saved, the last
//!   checkpoint, so removing it is one atomic step that also discards the checkpoint.
//! - **Temporary names.** Every file is written under `.name.partial` ([`temporary_name`]) and
//!   renamed when complete ([`DatasetDir::write_atomically`], [`DatasetDir::commit`]), so a
//!   crash never leaves a half-written file under its final name.
//! - **Checksums and durability.** Every finished file is recorded with its size and CRC-32C
//!   ([`FileRecord`]). [`DatasetDir::save_checkpoint`] first makes the files finished since the
//!   last checkpoint durable (fsync of the files, their folders and the marker), then records
//!   them with the format's state. At the end, `meta/surgvla_manifest.json` ([`MANIFEST`]) lists
//!   every file of the dataset with its size and checksum. Large files are written behind
//!   ([`WrittenBehind`]), so that the checkpoint's fsync finds them mostly on disk already.
//! - **Resume.** [`DatasetDir::resume`] refuses changed options before touching the folder,
//!   takes the lock, verifies every file the checkpoint lists (refusing, with the file named, if
//!   one is missing, truncated or changed) and deletes whatever was written after it.
//! - **Journals.** Append-only files of per-episode records ([`DatasetDir::append`]) that a
//!   format reads back when it finishes (all it did not hold within a bound), so what it keeps
//!   in memory does not grow past that bound with the number of episodes; a checkpoint
//!   records their length and checksum, resume cuts them back.
//! - **Rolling.** [`FileCounter`] numbers rolled files `chunk/file` the LeRobot way.

use crate::export::collection::{RecordedShard, SHARD_KEY};
use crate::export::error::ExportError;
use crate::export::error::OptionChange;
use crate::export::paths;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Name of the marker that exists while a dataset is being written.
pub const INCOMPLETE_MARKER: &str = ".surgvla-incomplete";
/// Every file of a finished dataset with its size and CRC-32C.
pub const MANIFEST: &str = "meta/surgvla_manifest.json";

pub use crate::files::temporary_name;

/// Writes `bytes` to `path` through a temporary name and a rename, making its folder first;
/// returns the size.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<u64, ExportError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
    }
    crate::files::write_atomically(path, bytes).map_err(|e| ExportError::Io {
        path: e.path,
        source: e.source,
    })
}

/// A finished file: its path relative to the root, size and CRC-32C (8 hex digits).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileRecord {
    pub path: String,
    pub bytes: u64,
    pub crc32c: String,
}

impl FileRecord {
    fn new(path: String, bytes: u64, crc: u32) -> Self {
        FileRecord {
            path,
            bytes,
            crc32c: format!("{crc:08x}"),
        }
    }

    /// What is wrong with the file at `path` compared with this record, if anything.
    /// As [`FileRecord::problem`], by the file's size alone (what `validate --quick` checks of
    /// the data and video files).
    pub fn size_problem(&self, path: &Path) -> Result<Option<String>, ExportError> {
        match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Some("is missing".into())),
            Err(source) => Err(ExportError::Io {
                path: path.into(),
                source,
            }),
            Ok(m) if !m.is_file() => Ok(Some("is not a regular file".into())),
            Ok(m) if m.len() != self.bytes => Ok(Some(format!(
                "is {} bytes, {} were recorded",
                m.len(),
                self.bytes
            ))),
            Ok(_) => Ok(None),
        }
    }

    pub fn problem(&self, path: &Path) -> Result<Option<String>, ExportError> {
        let file = match crate::files::open_regular(path) {
            Ok(file) => file,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Some("is missing".into()));
            }
            Err(e) if e.kind() == std::io::ErrorKind::InvalidInput => {
                return Ok(Some("is not a regular file".into()));
            }
            Err(source) => {
                return Err(ExportError::Io {
                    path: path.into(),
                    source,
                });
            }
        };
        let metadata = file.metadata().map_err(ExportError::io(path))?;
        if !metadata.is_file() {
            return Ok(Some("is not a regular file".into()));
        }
        if metadata.len() != self.bytes {
            let size = metadata.len();
            return Ok(Some(format!(
                "is {size} bytes, {} were recorded",
                self.bytes
            )));
        }
        // Read no further than one byte past the recorded size (a file may still be growing).
        let (bytes, crc) = checksum(file.take(self.bytes.saturating_add(1)), path)?;
        Ok(if bytes != self.bytes {
            Some(format!("is {bytes} bytes, {} were recorded", self.bytes))
        } else if format!("{crc:08x}") != self.crc32c {
            Some(format!(
                "has CRC-32C {crc:08x}, {} was recorded (its content changed)",
                self.crc32c
            ))
        } else {
            None
        })
    }
}

/// A writer that counts the bytes through it and their CRC-32C (what [`checksum`] would read
/// back), for [`DatasetDir::commit_summed`].
pub struct Checksummed<W> {
    inner: W,
    bytes: u64,
    crc: u32,
}

impl<W: Write> Checksummed<W> {
    pub fn new(inner: W) -> Self {
        Checksummed {
            inner,
            bytes: 0,
            crc: 0,
        }
    }

    /// The bytes written and their CRC-32C.
    pub fn sums(&self) -> (u64, u32) {
        (self.bytes, self.crc)
    }

    /// The writer it counted for.
    pub fn into_inner(self) -> W {
        self.inner
    }
}

impl Checksummed<WrittenBehind> {
    /// A file written behind, closed: its size and CRC-32C (for [`DatasetDir::commit_summed`])
    /// once its last write-behind request is done, or that request's error.
    pub fn finish(self) -> std::io::Result<(u64, u32)> {
        let sums = self.sums();
        self.inner.finish()?;
        Ok(sums)
    }
}

impl<W: Write> Write for Checksummed<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        let written = buf.get(..n).unwrap_or(buf);
        self.crc = crc32c::crc32c_append(self.crc, written);
        self.bytes += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Bytes of a file written between two requests of [`WrittenBehind`] to put them on disk.
const WRITE_BEHIND_BYTES: u64 = 16 << 20;

/// A large file written behind: every [`WRITE_BEHIND_BYTES`] written, a helper thread has the
/// kernel write what it holds of the file to disk (`sync_data` on a second handle) while the
/// writing goes on, so the checkpoint that makes the closed file durable finds little left to
/// write and does not stall the run. A helper's error comes back from the next write or from
/// [`WrittenBehind::finish`] (the kernel reports a failed write-back once: it is not lost).
pub struct WrittenBehind {
    file: File,
    since_request: u64,
    helper: Option<std::thread::JoinHandle<std::io::Result<()>>>,
    /// Requests made so far.
    requests: u64,
}

impl WrittenBehind {
    pub fn new(file: File) -> Self {
        WrittenBehind {
            file,
            since_request: 0,
            helper: None,
            requests: 0,
        }
    }

    /// Waits for the last request; its error, if any. Returns the requests made.
    pub fn finish(mut self) -> std::io::Result<u64> {
        self.reap(true)?;
        Ok(self.requests)
    }

    /// The finished helper's result (`wait`: waits for a running one).
    fn reap(&mut self, wait: bool) -> std::io::Result<()> {
        match self.helper.take() {
            Some(helper) if wait || helper.is_finished() => helper
                .join()
                .unwrap_or_else(|_| Err(std::io::Error::other("a write-behind helper panicked"))),
            running => {
                self.helper = running;
                Ok(())
            }
        }
    }
}

impl Write for WrittenBehind {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        self.since_request += n as u64;
        if self.since_request >= WRITE_BEHIND_BYTES {
            self.reap(false)?;
            // One request at a time: a disk slower than the writing gets the next one later.
            if self.helper.is_none() {
                self.since_request = 0;
                // No second handle or no thread to spare (a limit of the system) leaves the
                // work to the checkpoint's fsync: writing behind only saves time.
                let helper = (self.file.try_clone()).and_then(|handle| {
                    std::thread::Builder::new()
                        .name("surgvla-write-behind".into())
                        .spawn(move || handle.sync_data())
                });
                if let Ok(helper) = helper {
                    self.helper = Some(helper);
                    self.requests += 1;
                }
            }
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl Drop for WrittenBehind {
    /// No helper outlives its file's writer (an error was someone else's to report).
    fn drop(&mut self) {
        let _ = self.reap(true);
    }
}

/// The size and CRC-32C of a whole file.
pub(crate) fn checksum(mut file: impl Read, path: &Path) -> Result<(u64, u32), ExportError> {
    let mut buffer = vec![0u8; 1 << 20];
    let (mut bytes, mut crc) = (0u64, 0u32);
    loop {
        let n = file.read(&mut buffer).map_err(ExportError::io(path))?;
        if n == 0 {
            return Ok((bytes, crc));
        }
        crc = crc32c::crc32c_append(crc, &buffer[..n]);
        bytes += n as u64;
    }
}

/// The option every format records its name under (a field of each format's recorded options).
pub const FORMAT: &str = "format";

/// Everything a run's bytes depend on, by option name (e.g. `seed`, `video`, `features`): a
/// dataset records it when it starts, and a resume must give the same.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunOptions(BTreeMap<String, Value>);

impl RunOptions {
    /// The option naming the dataset a conversion reads ([`crate::export::identity`]): a
    /// resume must read the same one; it is not part of the [`RunOptions::digest`].
    pub const INPUT: &'static str = "input";

    /// The options `recorded` states: every field of a recorded-options struct (the dataset's
    /// or a format's), by its name; a field the struct does not skip is recorded even when
    /// `None` (as null).
    pub fn recorded(recorded: &impl Serialize) -> RunOptions {
        let mut options = RunOptions::default();
        if let Ok(value) = serde_json::to_value(recorded) {
            options.extend_from(&value);
        }
        options
    }

    /// The options read back as `T`, a recorded-options struct (the other options ignored);
    /// None when one it needs is missing or of another type.
    pub fn read<T: DeserializeOwned>(&self) -> Option<T> {
        let object = self.0.iter().map(|(k, v)| (k.clone(), v.clone()));
        serde_json::from_value(Value::Object(object.collect())).ok()
    }

    /// The name of the format the dataset is written in (None: a dataset that records no
    /// options, written by an older surgvla).
    pub fn format(&self) -> Option<&str> {
        self.0.get(FORMAT)?.as_str()
    }

    /// The run's shard as recorded (a collection's option; None when it records none).
    pub fn shard(&self) -> Option<&str> {
        self.0.get(SHARD_KEY)?.as_str()
    }

    /// Records the run's shard (None: as null, what a merge compares all but the shard with).
    pub fn set_shard(&mut self, shard: Option<&RecordedShard>) {
        let value = shard.map_or(Value::Null, |shard| shard.to_string().into());
        self.0.insert(SHARD_KEY.into(), value);
    }

    /// Records the input's identity (see [`RunOptions::INPUT`]).
    pub fn set_input(&mut self, input: &str) {
        self.0.insert(Self::INPUT.into(), input.into());
    }

    /// Records every key of a JSON object.
    fn extend_from(&mut self, object: &Value) {
        for (key, value) in object.as_object().into_iter().flatten() {
            self.0.insert(key.clone(), value.clone());
        }
    }

    /// Adds (or replaces) every option of `other`.
    pub fn merge(&mut self, other: RunOptions) {
        self.0.extend(other.0);
    }

    /// The options that shape the bytes: all but [`RunOptions::INPUT`] (the input's identity
    /// decides what may be resumed, not the bytes written), as a JSON object, keys sorted.
    pub fn shaping(&self) -> Value {
        let mut shaping = self.0.clone();
        shaping.remove(Self::INPUT);
        Value::Object(shaping.into_iter().collect())
    }

    /// The options a dataset's manifest records ([`RunOptions::shaping`]); empty when it
    /// records none (a dataset written before manifests did).
    pub fn from_manifest(manifest: &Value) -> RunOptions {
        let mut options = RunOptions::default();
        options.extend_from(&manifest["options"]);
        options
    }

    /// The value of `option`, if set.
    pub fn get(&self, option: &str) -> Option<&Value> {
        self.0.get(option)
    }

    /// CRC-32C of the options' canonical JSON (keys sorted), 8 hex digits.
    pub fn digest(&self) -> String {
        let text = serde_json::to_string(&self.shaping()).unwrap_or_default();
        format!("{:08x}", crc32c::crc32c(text.as_bytes()))
    }

    /// The options whose values differ from `given`'s, in name order.
    pub fn changes(&self, given: &RunOptions) -> Vec<OptionChange> {
        let names: BTreeSet<&String> = self.0.keys().chain(given.0.keys()).collect();
        names
            .into_iter()
            .filter(|name| self.0.get(*name) != given.0.get(*name))
            .map(|name| OptionChange {
                option: name.clone(),
                recorded: self.0.get(name).cloned(),
                given: given.0.get(name).cloned(),
            })
            .collect()
    }
}

/// Whether opening a sink with `resume` continues the dataset in `root` (it holds an
/// interrupted one) rather than starting a new one.
pub fn resumes(root: &Path, resume: bool) -> bool {
    resume && DatasetDir::is_interrupted(root)
}

/// After a conversion or merge into `out` failed: a usage error found before anything was
/// written (a feature the target cannot hold) leaves no output behind (the marker goes, and
/// the folder when the run `created` it), unless the run was a resume. Returns whether running
/// again with `--resume` continues it: after a failed write (a full disk) into a dataset left
/// interrupted, not after a damaged input.
pub fn after_failure(out: &Path, created: bool, resume: bool, usage: bool, write: bool) -> bool {
    if usage && !resume {
        DatasetDir::discard_unstarted(out, created);
    }
    write && DatasetDir::is_interrupted(out)
}

/// Which process holds a dataset folder.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Holder {
    pid: u32,
    host: String,
}

impl Holder {
    fn this_process() -> Self {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .map(|h| h.trim().to_string())
            .unwrap_or_else(|_| "this machine".into());
        Holder {
            pid: std::process::id(),
            host,
        }
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "surgvla process {} on {}", self.pid, self.host)
    }
}

/// The marker's content.
#[derive(Serialize, Deserialize)]
struct Marker<T> {
    note: String,
    holder: Holder,
    options_digest: String,
    options: RunOptions,
    checkpoint: Option<Checkpoint<T>>,
}

/// What a checkpoint records: the finished files, the journals' lengths, the format's state,
/// and renames of finished files that may have begun after it (undone by a resume).
#[derive(Serialize, Deserialize)]
struct Checkpoint<T> {
    files: Vec<FileRecord>,
    journals: BTreeMap<String, JournalMark>,
    state: T,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    renames: Vec<(String, String)>,
    /// Files the run may rewrite after this checkpoint (a zarr chunk written partly filled,
    /// rewritten whole when it fills): a resume checks only that they are there, and the format
    /// checks their content against its state.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    rewritable: Vec<String>,
}

/// A journal's length and the CRC-32C of its bytes up to there.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
struct JournalMark {
    bytes: u64,
    crc32c: u32,
}

/// An append-only file of records, one per line.
#[derive(Debug)]
struct Journal {
    writer: BufWriter<File>,
    mark: JournalMark,
}

/// A dataset folder being written.
#[derive(Debug)]
pub struct DatasetDir {
    root: PathBuf,
    /// The folder's lock, held while this value lives.
    _lock: File,
    holder: Holder,
    options: RunOptions,
    /// Finished files, in the order they finished.
    files: Vec<FileRecord>,
    /// How many of `files` a checkpoint made durable.
    synced: usize,
    journals: BTreeMap<String, Journal>,
    /// Renames being made ([`DatasetDir::rename_files`]), recorded with the next checkpoint.
    renames: Vec<(String, String)>,
    /// Files the checkpoint being saved lets the run rewrite
    /// ([`DatasetDir::save_checkpoint_rewritable`]).
    rewritable: Vec<String>,
}

fn sync_dir(path: &Path) -> Result<(), ExportError> {
    File::open(path)
        .and_then(|dir| dir.sync_all())
        .map_err(ExportError::io(path))
}

impl DatasetDir {
    /// Starts a dataset in `root`, which must not exist or be empty: takes the lock, then writes
    /// the marker with `options`.
    pub fn create(root: &Path, options: &RunOptions) -> Result<Self, ExportError> {
        let output = |source| ExportError::Output {
            path: root.to_path_buf(),
            source,
        };
        if root.exists() && !root.is_dir() {
            return Err(output(std::io::Error::from(
                std::io::ErrorKind::NotADirectory,
            )));
        }
        std::fs::create_dir_all(root).map_err(output)?;
        let lock = lock(root)?;
        let mut entries = std::fs::read_dir(root).map_err(output)?;
        if entries.next().is_some() {
            return Err(ExportError::NotEmpty {
                path: root.to_path_buf(),
                interrupted: Self::is_interrupted(root),
            });
        }
        let dir = DatasetDir::locked(root, lock, options);
        // A marker that cannot be written (read-only, no permission) is the output's problem,
        // except a full disk, which is the work's.
        dir.write_marker::<()>(None).map_err(|e| match e {
            ExportError::Io { path, source }
                if source.kind() != std::io::ErrorKind::StorageFull =>
            {
                ExportError::Output { path, source }
            }
            other => other,
        })?;
        Ok(dir)
    }

    /// This process's hold on `root`, with no file recorded yet.
    fn locked(root: &Path, lock: File, options: &RunOptions) -> Self {
        DatasetDir {
            root: root.to_path_buf(),
            _lock: lock,
            holder: Holder::this_process(),
            options: options.clone(),
            files: Vec::new(),
            synced: 0,
            journals: BTreeMap::new(),
            renames: Vec::new(),
            rewritable: Vec::new(),
        }
    }

    /// Whether `root` holds an interrupted dataset (one with the marker).
    pub fn is_interrupted(root: &Path) -> bool {
        root.join(INCOMPLETE_MARKER).exists()
    }

    /// Removes what a run that stopped before writing anything left in `root`: the marker, when
    /// it is the folder's only entry, and then the folder itself when the run `created` it.
    /// Anything else in the folder leaves it untouched. Returns whether it removed the marker.
    pub fn discard_unstarted(root: &Path, created: bool) -> bool {
        let Ok(entries) = std::fs::read_dir(root) else {
            return false;
        };
        let names: Vec<std::ffi::OsString> = entries
            .take(2)
            .filter_map(|entry| entry.ok().map(|entry| entry.file_name()))
            .collect();
        if names.len() != 1 || names[0] != INCOMPLETE_MARKER {
            return false;
        }
        if std::fs::remove_file(root.join(INCOMPLETE_MARKER)).is_err() {
            return false;
        }
        if created {
            std::fs::remove_dir(root).ok();
        }
        true
    }

    /// Reopens the interrupted dataset in `root`. Refuses, before changing anything, when it
    /// has no marker or was started with other `options`; then takes the lock, verifies every
    /// file of the last checkpoint, deletes every other file under `folders` (what was written
    /// after the checkpoint) and cuts the journals back. Returns the format's saved state.
    pub fn resume<T: DeserializeOwned>(
        root: &Path,
        options: &RunOptions,
        folders: &[&str],
    ) -> Result<(Self, Option<T>), ExportError> {
        // Links first: nothing of the folder is trusted before it is known to hold none.
        if let Some(link) = first_link(root) {
            return Err(holds_link(root, &link));
        }
        let recorded: Marker<serde::de::IgnoredAny> = read_marker(root)?;
        let changes = recorded.options.changes(options);
        if !changes.is_empty() {
            return Err(ExportError::OptionsChanged {
                path: root.to_path_buf(),
                changes,
            });
        }
        let lock = lock(root)?;
        let marker: Marker<Value> = read_marker(root)?;
        let mut dir = DatasetDir::locked(root, lock, options);
        let Some(checkpoint) = marker.checkpoint else {
            dir.remove_files_except(folders, &HashSet::new())?;
            dir.write_marker::<()>(None)?;
            return Ok((dir, None));
        };
        let state = T::deserialize(&checkpoint.state).map_err(|e| ExportError::NotResumable {
            path: root.to_path_buf(),
            reason: format!("its checkpoint is unreadable ({e})"),
        })?;
        // Renames an interrupted finish began go back, so the checkpoint's names hold again.
        for (from, to) in &checkpoint.renames {
            let (from, to) = (dir.path(from), dir.path(to));
            if !from.exists() && to.exists() {
                std::fs::rename(&to, &from).map_err(ExportError::io(&from))?;
            }
        }
        for record in &checkpoint.files {
            let path = dir.path(&record.path);
            let problem = if checkpoint.rewritable.contains(&record.path) {
                (!path.is_file()).then(|| "is missing".to_string())
            } else {
                record.problem(&path)?
            };
            if let Some(problem) = problem {
                return Err(ExportError::Damaged { path, problem });
            }
        }
        let mut keep: HashSet<String> = checkpoint.files.iter().map(|f| f.path.clone()).collect();
        keep.extend(checkpoint.journals.keys().cloned());
        dir.remove_files_except(folders, &keep)?;
        for (name, mark) in checkpoint.journals {
            let journal = dir.reopen_journal(&name, mark)?;
            dir.journals.insert(name, journal);
        }
        dir.synced = checkpoint.files.len();
        dir.files = checkpoint.files;
        // The same checkpoint, now naming this process as the holder.
        dir.write_marker(Some(&checkpoint.state))?;
        Ok((dir, Some(state)))
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The path of `relative` inside the dataset.
    pub fn path(&self, relative: &str) -> PathBuf {
        self.root.join(relative)
    }

    /// The path of `relative` inside the dataset, for writing: refused when its text could
    /// lead outside (a file name made from another dataset's metadata; see [`paths`]).
    fn checked(&self, relative: &str) -> Result<PathBuf, ExportError> {
        paths::relative(relative)
            .map(|r| self.root.join(r))
            .map_err(|problem| ExportError::UnsafeName {
                path: self.root.clone(),
                what: "file name",
                name: relative.to_string(),
                problem,
            })
    }

    /// `path` relative to the root, with `/` separators.
    pub fn relative(&self, path: &Path) -> String {
        path.strip_prefix(&self.root)
            .unwrap_or(path)
            .to_string_lossy()
            .into_owned()
    }

    /// The files finished so far.
    pub fn files(&self) -> &[FileRecord] {
        &self.files
    }

    fn record(&mut self, record: FileRecord) {
        if let Some(i) = self.files.iter().position(|f| f.path == record.path) {
            // Rewritten (a metadata file after a resume): it is not durable any more.
            self.files.remove(i);
            self.synced = self.synced.min(i);
        }
        self.files.push(record);
    }

    /// Writes a whole file of the dataset under a temporary name, renames it and records it;
    /// returns its size.
    pub fn write_atomically(&mut self, relative: &str, bytes: &[u8]) -> Result<u64, ExportError> {
        let size = write_atomically(&self.checked(relative)?, bytes)?;
        self.record(FileRecord::new(
            relative.to_string(),
            size,
            crc32c::crc32c(bytes),
        ));
        Ok(size)
    }

    /// Writes a file that rides along with the dataset but is not part of it (a run report
    /// whose timings differ between runs): not in the manifest.
    pub fn write_unlisted(&self, relative: &str, bytes: &[u8]) -> Result<u64, ExportError> {
        write_atomically(&self.checked(relative)?, bytes)
    }

    /// Opens `relative` for writing under its temporary name (folders created).
    pub fn create_file(&self, relative: &str) -> Result<(File, PendingFile), ExportError> {
        let path = self.checked(relative)?;
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
        }
        let temporary = temporary_name(&path);
        // Never through a link: a leftover temporary file (or link) is replaced, not followed.
        if std::fs::symlink_metadata(&temporary).is_ok() {
            std::fs::remove_file(&temporary).map_err(ExportError::io(&temporary))?;
        }
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&temporary)
            .map_err(ExportError::io(&temporary))?;
        Ok((file, PendingFile { path, temporary }))
    }

    /// Gives a closed file its final name and records it; returns its size.
    pub fn commit(&mut self, pending: PendingFile) -> Result<u64, ExportError> {
        std::fs::rename(&pending.temporary, &pending.path)
            .map_err(ExportError::io(&pending.path))?;
        let file = File::open(&pending.path).map_err(ExportError::io(&pending.path))?;
        let (bytes, crc) = checksum(file, &pending.path)?;
        self.record(FileRecord::new(self.relative(&pending.path), bytes, crc));
        Ok(bytes)
    }

    /// [`DatasetDir::commit`] for a file written through a [`Checksummed`] writer: its size and
    /// CRC-32C as counted while it was written, not read back.
    pub fn commit_summed(
        &mut self,
        pending: PendingFile,
        (bytes, crc): (u64, u32),
    ) -> Result<u64, ExportError> {
        std::fs::rename(&pending.temporary, &pending.path)
            .map_err(ExportError::io(&pending.path))?;
        self.record(FileRecord::new(self.relative(&pending.path), bytes, crc));
        Ok(bytes)
    }

    /// Appends one record (a line) to the journal `relative` (created on first use).
    pub fn append(&mut self, relative: &str, line: &[u8]) -> Result<(), ExportError> {
        if !self.journals.contains_key(relative) {
            let path = self.path(relative);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
            }
            let file = File::create(&path).map_err(ExportError::io(&path))?;
            self.journals.insert(
                relative.to_string(),
                Journal {
                    writer: BufWriter::new(file),
                    mark: JournalMark::default(),
                },
            );
        }
        let path = self.path(relative);
        let journal = self
            .journals
            .get_mut(relative)
            .ok_or_else(|| ExportError::Internal(format!("no journal {relative}")))?;
        for part in [line, b"\n"] {
            journal
                .writer
                .write_all(part)
                .map_err(ExportError::io(&path))?;
            journal.mark.crc32c = crc32c::crc32c_append(journal.mark.crc32c, part);
            journal.mark.bytes += part.len() as u64;
        }
        Ok(())
    }

    /// The records of journal `relative`, in order (none if it was never written).
    pub fn journal_lines(
        &mut self,
        relative: &str,
    ) -> Result<impl Iterator<Item = Result<String, ExportError>> + use<>, ExportError> {
        let path = self.path(relative);
        let lines = match self.journals.get_mut(relative) {
            Some(journal) => {
                journal.writer.flush().map_err(ExportError::io(&path))?;
                let file = File::open(&path).map_err(ExportError::io(&path))?;
                Some(BufReader::new(file).lines())
            }
            None => None,
        };
        Ok(lines
            .into_iter()
            .flatten()
            .map(move |line| line.map_err(ExportError::io(&path))))
    }

    /// Journal `relative`'s records as one file's bytes (a line each).
    pub fn journal_bytes(&mut self, relative: &str) -> Result<Vec<u8>, ExportError> {
        let mut bytes = Vec::new();
        for line in self.journal_lines(relative)? {
            bytes.extend_from_slice(line?.as_bytes());
            bytes.push(b'\n');
        }
        Ok(bytes)
    }

    fn reopen_journal(&self, relative: &str, mark: JournalMark) -> Result<Journal, ExportError> {
        let path = self.path(relative);
        let damaged = |problem: String| ExportError::Damaged {
            path: path.clone(),
            problem,
        };
        let file = File::open(&path).map_err(|_| damaged("is missing".into()))?;
        let mut prefix = Vec::new();
        file.take(mark.bytes)
            .read_to_end(&mut prefix)
            .map_err(ExportError::io(&path))?;
        if prefix.len() as u64 != mark.bytes {
            return Err(damaged(format!(
                "is {} bytes, {} were recorded",
                prefix.len(),
                mark.bytes
            )));
        }
        if crc32c::crc32c(&prefix) != mark.crc32c {
            return Err(damaged("its recorded part changed".into()));
        }
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .map_err(ExportError::io(&path))?;
        file.set_len(mark.bytes).map_err(ExportError::io(&path))?;
        let mut writer = BufWriter::new(file);
        std::io::Seek::seek(&mut writer, std::io::SeekFrom::End(0))
            .map_err(ExportError::io(&path))?;
        Ok(Journal { writer, mark })
    }

    /// Makes every file finished since the last call durable: the files, the journals and
    /// their folders.
    fn sync(&mut self) -> Result<(), ExportError> {
        let mut folders = BTreeSet::new();
        for record in &self.files[self.synced..] {
            let path = self.path(&record.path);
            File::open(&path)
                .and_then(|f| f.sync_all())
                .map_err(ExportError::io(&path))?;
            if let Some(parent) = path.parent() {
                folders.insert(parent.to_path_buf());
            }
        }
        for (relative, journal) in &mut self.journals {
            let path = self.root.join(relative);
            journal.writer.flush().map_err(ExportError::io(&path))?;
            journal
                .writer
                .get_ref()
                .sync_data()
                .map_err(ExportError::io(&path))?;
            if let Some(parent) = path.parent() {
                folders.insert(parent.to_path_buf());
            }
        }
        for folder in folders {
            sync_dir(&folder)?;
        }
        self.synced = self.files.len();
        Ok(())
    }

    fn write_marker<T: Serialize>(&self, state: Option<&T>) -> Result<(), ExportError> {
        let marker = Marker {
            note: "surgvla is writing this dataset; it is not complete".into(),
            holder: self.holder.clone(),
            options_digest: self.options.digest(),
            options: self.options.clone(),
            checkpoint: state.map(|state| Checkpoint {
                files: self.files.clone(),
                journals: self
                    .journals
                    .iter()
                    .map(|(name, j)| (name.clone(), j.mark))
                    .collect(),
                state,
                renames: self.renames.clone(),
                rewritable: self.rewritable.clone(),
            }),
        };
        let path = self.path(INCOMPLETE_MARKER);
        let temporary = temporary_name(&path);
        let file = File::create(&temporary).map_err(ExportError::io(&temporary))?;
        // Streamed: the checkpoint's state (statistics reservoirs) is never held as text.
        let mut writer = BufWriter::new(file);
        serde_json::to_writer(&mut writer, &marker).map_err(|source| {
            if source.is_io() {
                // A full disk stays a full disk (its hint says to free space and resume).
                ExportError::Io {
                    path: temporary.clone(),
                    source: source.into(),
                }
            } else {
                ExportError::Json {
                    path: path.clone(),
                    source,
                }
            }
        })?;
        let file = writer.into_inner().map_err(|e| ExportError::Io {
            path: temporary.clone(),
            source: e.into_error(),
        })?;
        file.sync_all().map_err(ExportError::io(&temporary))?;
        std::fs::rename(&temporary, &path).map_err(ExportError::io(&path))?;
        sync_dir(&self.root)
    }

    /// Records a format's state at a moment when every file it wrote is complete: makes those
    /// files durable, then writes the checkpoint (into the marker).
    pub fn save_checkpoint<T: Serialize>(&mut self, state: &T) -> Result<(), ExportError> {
        self.sync()?;
        self.write_marker(Some(state))
    }

    /// [`DatasetDir::save_checkpoint`], where the files `rewritable` (relative paths) may be
    /// rewritten before the next checkpoint: a resume from this one then checks only that they
    /// exist, and the format checks what it reads back of them (see [`Checkpoint`]).
    pub fn save_checkpoint_rewritable<T: Serialize>(
        &mut self,
        state: &T,
        rewritable: Vec<String>,
    ) -> Result<(), ExportError> {
        self.rewritable = rewritable;
        let saved = self.save_checkpoint(state);
        self.rewritable.clear();
        saved
    }

    /// Gives finished files new names (`(from, to)` relative paths; e.g. shards whose count is
    /// known only at the end). A checkpoint with `state` first records the renames, so a resume
    /// after an interruption here undoes those already made; then each file is renamed and its
    /// record follows it.
    pub fn rename_files<T: Serialize>(
        &mut self,
        renames: &[(String, String)],
        state: &T,
    ) -> Result<(), ExportError> {
        self.renames = renames.to_vec();
        let saved = self.save_checkpoint(state);
        self.renames.clear();
        saved?;
        let mut folders = BTreeSet::new();
        for (from, to) in renames {
            let (from_path, to_path) = (self.path(from), self.path(to));
            std::fs::rename(&from_path, &to_path).map_err(ExportError::io(&to_path))?;
            if let Some(record) = self.files.iter_mut().find(|f| &f.path == from) {
                record.path = to.clone();
            }
            if let Some(parent) = to_path.parent() {
                folders.insert(parent.to_path_buf());
            }
        }
        for folder in folders {
            sync_dir(&folder)?;
        }
        Ok(())
    }

    /// Deletes every file under `folders` (`""`: the whole folder) whose relative path is not
    /// in `keep` (what was written after the last checkpoint, including temporary files); never
    /// the marker. Refuses, before deleting anything, when the folders hold a symbolic link:
    /// surgvla never makes one, and following it would delete files outside the dataset.
    fn remove_files_except(
        &self,
        folders: &[&str],
        keep: &HashSet<String>,
    ) -> Result<(), ExportError> {
        let mut doomed = Vec::new();
        for folder in folders {
            let mut pending = vec![self.path(folder)];
            while let Some(dir) = pending.pop() {
                let Ok(entries) = std::fs::read_dir(&dir) else {
                    continue;
                };
                for entry in entries {
                    let entry = entry.map_err(ExportError::io(&dir))?;
                    let path = entry.path();
                    let kind = entry.file_type().map_err(ExportError::io(&path))?;
                    let relative = self.relative(&path);
                    if kind.is_symlink() {
                        return Err(holds_link(&self.root, &relative));
                    }
                    // The marker is never pruned, even when a format owns the whole folder.
                    let marker = relative == INCOMPLETE_MARKER
                        || relative == format!(".{INCOMPLETE_MARKER}.partial");
                    if kind.is_dir() {
                        pending.push(path);
                    } else if !marker && !keep.contains(&relative) {
                        doomed.push(path);
                    }
                }
            }
        }
        for path in doomed {
            std::fs::remove_file(&path).map_err(ExportError::io(&path))?;
        }
        Ok(())
    }

    /// Writes the manifest `relative` (every recorded file, by path; [`MANIFEST`] in LeRobot);
    /// returns its size. The dataset is complete once [`DatasetDir::complete`] follows.
    pub fn write_manifest(&mut self, relative: &str) -> Result<u64, ExportError> {
        let mut files = self.files.clone();
        files.retain(|f| f.path != relative);
        files.sort_by(|a, b| a.path.cmp(&b.path));
        // The options themselves, so that a merge can check its inputs agree and write what
        // one run writes (RunOptions::from_manifest).
        let manifest = serde_json::json!({
            "checksum": "crc32c",
            "options_digest": self.options.digest(),
            "options": self.options.shaping(),
            "files": files,
        });
        let text = serde_json::to_vec_pretty(&manifest).map_err(|source| ExportError::Json {
            path: self.path(relative),
            source,
        })?;
        self.write_atomically(relative, &text)
    }

    /// Marks the dataset complete: makes everything durable, then, when there are journals
    /// (which the checkpoint needs), replaces the checkpoint by none and removes them, then
    /// removes the marker in one step. Interrupted in between, the folder is still marked
    /// incomplete, and a resume starts the run over in it (the same bytes): never a finished
    /// dataset with a journal left in it. Calling it again does nothing.
    pub fn complete(&mut self) -> Result<(), ExportError> {
        let marker = self.path(INCOMPLETE_MARKER);
        if marker.exists() {
            self.sync()?;
            sync_dir(&self.root)?;
            if !self.journals.is_empty() {
                self.write_marker::<()>(None)?;
            }
        }
        for relative in std::mem::take(&mut self.journals).into_keys() {
            let path = self.path(&relative);
            std::fs::remove_file(&path).map_err(ExportError::io(&path))?;
        }
        if marker.exists() {
            sync_dir(&self.root)?;
            std::fs::remove_file(&marker).map_err(ExportError::io(&marker))?;
            sync_dir(&self.root)?;
        }
        Ok(())
    }
}

/// The first symbolic link inside `root` (relative, `/`-separated), in name order.
fn first_link(root: &Path) -> Option<String> {
    let mut pending = vec![root.to_path_buf()];
    while let Some(dir) = pending.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut entries: Vec<_> = entries.flatten().collect();
        entries.sort_by_key(|e| e.file_name());
        for entry in entries {
            match entry.file_type() {
                Ok(kind) if kind.is_symlink() => {
                    let path = entry.path();
                    let relative = path.strip_prefix(root).unwrap_or(&path);
                    return Some(relative.to_string_lossy().replace('\\', "/"));
                }
                Ok(kind) if kind.is_dir() => pending.push(entry.path()),
                _ => {}
            }
        }
    }
    None
}

/// Resuming refused: the dataset holds a link, which surgvla never makes.
fn holds_link(root: &Path, link: &str) -> ExportError {
    ExportError::NotResumable {
        path: root.to_path_buf(),
        reason: format!(
            "it holds the symbolic link {link}, which surgvla never makes (resuming would write or delete through it); delete the folder and run again"
        ),
    }
}

/// How long [`lock`] waits for a lock this very process held and released: a child process
/// forked by another thread holds a copy of the closed descriptor until it execs.
const OWN_LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Locks `root` (an advisory `flock` on the folder itself, so no lock file is left behind).
pub fn lock(root: &Path) -> Result<File, ExportError> {
    let file = File::open(root).map_err(|source| ExportError::Output {
        path: root.to_path_buf(),
        source,
    })?;
    let started = std::time::Instant::now();
    let mut attempt = file.try_lock();
    // The lock of a writer this process dropped may linger for the moment a child forked by
    // another thread takes to exec (the descriptor is close-on-exec, not close-on-fork).
    while matches!(attempt, Err(std::fs::TryLockError::WouldBlock))
        && started.elapsed() < OWN_LOCK_WAIT
        && read_marker::<serde::de::IgnoredAny>(root)
            .is_ok_and(|m| m.holder.pid == std::process::id())
    {
        std::thread::sleep(std::time::Duration::from_millis(10));
        attempt = file.try_lock();
    }
    match attempt {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => Err(ExportError::Locked {
            path: root.to_path_buf(),
            holder: read_marker::<serde::de::IgnoredAny>(root)
                .map(|m| m.holder.to_string())
                .unwrap_or_else(|_| "another surgvla process".into()),
        }),
        // A file system without locks: go on unlocked.
        Err(std::fs::TryLockError::Error(e)) if e.kind() == std::io::ErrorKind::Unsupported => {
            Ok(file)
        }
        Err(std::fs::TryLockError::Error(source)) => Err(ExportError::Output {
            path: root.to_path_buf(),
            source,
        }),
    }
}

/// The largest marker read back (its checkpoint's state included).
const MAX_MARKER_BYTES: u64 = 1 << 30;

fn read_marker<T: DeserializeOwned>(root: &Path) -> Result<Marker<T>, ExportError> {
    let path = root.join(INCOMPLETE_MARKER);
    let not_resumable = |reason: String| ExportError::NotResumable {
        path: root.to_path_buf(),
        reason,
    };
    if !path.exists() {
        return Err(not_resumable(format!(
            "it is not an interrupted surgvla dataset (no {INCOMPLETE_MARKER} marker)"
        )));
    }
    // A checkpoint holds the format's state, statistics reservoirs included (tens of MB for
    // a large collection): a larger cap than other metadata's.
    let bytes = crate::export::bounded::read_capped(&path, MAX_MARKER_BYTES)?;
    serde_json::from_slice(&bytes).map_err(|e| {
        not_resumable(format!(
            "its marker {} is unreadable ({e}); it was started by another surgvla version or damaged",
            path.display()
        ))
    })
}

/// A file being written under its temporary name.
#[derive(Debug)]
pub struct PendingFile {
    /// The final name.
    pub path: PathBuf,
    temporary: PathBuf,
}

impl PendingFile {
    /// Bytes written so far.
    pub fn bytes_so_far(&self) -> u64 {
        std::fs::metadata(&self.temporary).map_or(0, |m| m.len())
    }
}

/// Numbers rolled files: `chunks_size` files to a chunk folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileCounter {
    pub chunks_size: u64,
    /// How many files were started.
    pub next: u64,
}

impl FileCounter {
    pub fn new(chunks_size: u64) -> Self {
        FileCounter {
            chunks_size: chunks_size.max(1),
            next: 0,
        }
    }

    /// (chunk, file) of `counter`.
    pub fn location(&self, counter: u64) -> (u64, u64) {
        (counter / self.chunks_size, counter % self.chunks_size)
    }

    /// (chunk, file) of the next file, counted.
    pub fn take(&mut self) -> (u64, u64) {
        let location = self.location(self.next);
        self.next += 1;
        location
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let root = std::env::temp_dir().join(format!("surgvla-dir-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&root).ok();
        root
    }

    fn options(seed: u64) -> RunOptions {
        RunOptions::recorded(&serde_json::json!({"seed": seed, "format": "lerobot"}))
    }

    /// A file written behind holds exactly what was written, and asked the kernel to put it
    /// on disk as it went (one request per 16 MiB at most, none left running).
    #[test]
    fn a_file_written_behind_holds_its_bytes_and_asked_for_disk_on_the_way() {
        let root = std::env::temp_dir().join(format!("surgvla-behind-{}", std::process::id()));
        std::fs::create_dir_all(&root).expect("folder");
        let path = root.join("big.bin");
        let mut rng = crate::rng::SplitMix64::new(5);
        let bytes: Vec<u8> = (0..(40 << 20) + 12_345)
            .map(|_| rng.next_u64() as u8)
            .collect();
        let mut writer = WrittenBehind::new(File::create(&path).expect("file"));
        let mut at = 0;
        while at < bytes.len() {
            let n = (1 + rng.next_u64() % (3 << 20)) as usize;
            let end = (at + n).min(bytes.len());
            writer.write_all(&bytes[at..end]).expect("write");
            at = end;
        }
        let requests = writer.finish().expect("every request succeeded");
        assert!(
            (1..=2).contains(&requests),
            "{requests} requests for 40 MiB"
        );
        assert!(std::fs::read(&path).expect("read") == bytes);
        std::fs::remove_dir_all(&root).expect("clean up");
    }

    /// What a checksummed writer counts is what reading the bytes back gives, however they
    /// were split into writes, in memory and in a file written behind.
    #[test]
    fn a_checksummed_writer_counts_what_reading_back_gives() {
        let mut rng = crate::rng::SplitMix64::new(7);
        let bytes: Vec<u8> = (0..100_000).map(|_| rng.next_u64() as u8).collect();
        let mut writer = Checksummed::new(Vec::new());
        let mut at = 0;
        while at < bytes.len() {
            let n = (1 + rng.next_u64() % 9_000) as usize;
            let end = (at + n).min(bytes.len());
            writer.write_all(&bytes[at..end]).expect("write");
            at = end;
        }
        let sums = writer.sums();
        assert_eq!(writer.inner, bytes);
        assert_eq!(sums, checksum(&bytes[..], Path::new("x")).expect("read"));
        assert_ne!(sums.1, 0);
        let root = scratch("checksummed-behind");
        std::fs::create_dir_all(&root).expect("folder");
        let path = root.join("counted.bin");
        let mut file = Checksummed::new(WrittenBehind::new(File::create(&path).expect("file")));
        file.write_all(&bytes).expect("write");
        let closed = file.finish().expect("closed");
        let reread = checksum(File::open(&path).expect("open"), &path).expect("read");
        assert_eq!(closed, reread);
        assert_eq!(closed, sums);
        std::fs::remove_dir_all(&root).expect("clean up");
    }

    #[test]
    fn a_checkpoint_larger_than_other_metadata_resumes() {
        // A large collection's checkpoint (statistics reservoirs) is over the 32 MiB cap of
        // other metadata documents; the marker has its own cap.
        let root = scratch("big-checkpoint");
        let state = "x".repeat((crate::export::bounded::MAX_METADATA_BYTES + 1024) as usize);
        {
            let mut dir = DatasetDir::create(&root, &options(1)).expect("create");
            dir.save_checkpoint(&state).expect("checkpoint");
        }
        let (_, resumed) = DatasetDir::resume::<String>(&root, &options(1), &[]).expect("resume");
        assert_eq!(resumed.map(|s| s.len()), Some(state.len()));
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn a_folder_is_incomplete_until_completed_and_refused_when_not_empty() {
        let root = scratch("marker");
        let mut dir = DatasetDir::create(&root, &options(1)).expect("create");
        assert!(DatasetDir::is_interrupted(&root));
        drop(dir);
        assert!(matches!(
            DatasetDir::create(&root, &options(1)),
            Err(ExportError::NotEmpty {
                interrupted: true,
                ..
            })
        ));
        let (resumed, state) =
            DatasetDir::resume::<Vec<u32>>(&root, &options(1), &["meta"]).expect("resume");
        assert_eq!(state, None);
        dir = resumed;
        dir.write_atomically("meta/a.json", b"{}").expect("write");
        assert!(!temporary_name(&root.join("meta/a.json")).exists());
        dir.save_checkpoint(&vec![1u32, 2]).expect("checkpoint");
        drop(dir);
        let (mut dir, state) =
            DatasetDir::resume::<Vec<u32>>(&root, &options(1), &["meta"]).expect("resume");
        assert_eq!(state, Some(vec![1, 2]));
        assert_eq!(dir.files().len(), 1);
        dir.write_manifest(MANIFEST).expect("manifest");
        dir.complete().expect("complete");
        dir.complete().expect("complete twice");
        assert!(!DatasetDir::is_interrupted(&root));
        assert!(DatasetDir::resume::<Vec<u32>>(&root, &options(1), &[]).is_err());
        let manifest = std::fs::read_to_string(root.join(MANIFEST)).expect("manifest");
        let crc = format!("{:08x}", crc32c::crc32c(b"{}"));
        assert!(
            manifest.contains("meta/a.json") && manifest.contains(&crc),
            "{manifest}"
        );
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn a_resume_with_other_options_names_them_and_touches_nothing() {
        let root = scratch("options");
        drop(DatasetDir::create(&root, &options(1)).expect("create"));
        let marker = std::fs::read(root.join(INCOMPLETE_MARKER)).expect("marker");
        let mut other = options(2);
        other.merge(RunOptions::recorded(&serde_json::json!({"video": "h264"})));
        match DatasetDir::resume::<()>(&root, &other, &["meta"]) {
            Err(ExportError::OptionsChanged { changes, .. }) => {
                let said: Vec<String> = changes.iter().map(ToString::to_string).collect();
                assert_eq!(
                    said,
                    ["seed was 1, now 2", "video was (none), now \"h264\""]
                );
            }
            other => panic!("expected OptionsChanged, got {other:?}"),
        }
        assert_eq!(
            std::fs::read(root.join(INCOMPLETE_MARKER)).expect("marker"),
            marker
        );
        assert_ne!(options(1).digest(), options(2).digest());
        assert_eq!(options(1).digest(), options(1).digest());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn the_folder_is_locked_while_a_run_holds_it() {
        let root = scratch("lock");
        let dir = DatasetDir::create(&root, &options(1)).expect("create");
        match DatasetDir::resume::<()>(&root, &options(1), &[]) {
            Err(ExportError::Locked { holder, .. }) => {
                assert!(holder.contains(&std::process::id().to_string()), "{holder}");
            }
            other => panic!("expected Locked, got {other:?}"),
        }
        drop(dir);
        assert!(DatasetDir::resume::<()>(&root, &options(1), &[]).is_ok());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn journals_and_files_go_back_to_the_checkpoint_on_resume() {
        let root = scratch("journal");
        let mut dir = DatasetDir::create(&root, &options(1)).expect("create");
        dir.append("meta/.rows", b"one").expect("append");
        let (mut file, pending) = dir.create_file("data/a.bin").expect("open");
        std::io::Write::write_all(&mut file, b"abc").expect("write");
        drop(file);
        assert_eq!(pending.bytes_so_far(), 3);
        assert_eq!(dir.commit(pending).expect("commit"), 3);
        dir.save_checkpoint(&7u32).expect("checkpoint");
        // After the checkpoint: a row and a file that a resume must drop.
        dir.append("meta/.rows", b"two").expect("append");
        dir.write_atomically("data/b.bin", b"x").expect("write");
        drop(dir);
        let (mut dir, state) =
            DatasetDir::resume::<u32>(&root, &options(1), &["data", "meta"]).expect("resume");
        assert_eq!(state, Some(7));
        assert!(root.join("data/a.bin").exists());
        assert!(!root.join("data/b.bin").exists());
        let rows: Vec<String> = dir
            .journal_lines("meta/.rows")
            .expect("lines")
            .collect::<Result<_, _>>()
            .expect("read");
        assert_eq!(rows, ["one"]);
        dir.complete().expect("complete");
        assert!(!root.join("meta/.rows").exists());
        std::fs::remove_dir_all(&root).ok();
    }

    /// Completing stops between the journals and the marker (here: a journal that cannot be
    /// removed): the folder is still marked incomplete, its checkpoint gone, so a resume starts
    /// over rather than leave a finished-looking dataset holding a journal.
    #[test]
    fn a_completion_cut_short_leaves_a_folder_that_resumes_from_the_start() {
        let root = scratch("complete-cut");
        let mut dir = DatasetDir::create(&root, &options(1)).expect("create");
        dir.append("meta/.rows", b"one").expect("append");
        dir.write_atomically("data/a.bin", b"abc").expect("write");
        dir.save_checkpoint(&7u32).expect("checkpoint");
        // The journal replaced by a folder holding a file: removing it fails.
        std::fs::remove_file(root.join("meta/.rows")).expect("journal");
        std::fs::create_dir_all(root.join("meta/.rows/x")).expect("folder");
        assert!(dir.complete().is_err());
        drop(dir);
        assert!(DatasetDir::is_interrupted(&root));
        std::fs::remove_dir_all(root.join("meta/.rows")).expect("folder");
        let (_, state) =
            DatasetDir::resume::<u32>(&root, &options(1), &["data", "meta"]).expect("resume");
        assert_eq!(state, None, "no checkpoint: the run starts over");
        assert!(!root.join("data/a.bin").exists());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn renames_interrupted_halfway_are_undone_by_a_resume() {
        let root = scratch("rename");
        let mut dir = DatasetDir::create(&root, &options(1)).expect("create");
        dir.write_atomically("data/a-0", b"zero").expect("write");
        dir.write_atomically("data/a-1", b"one").expect("write");
        let renames = [
            ("data/a-0".to_string(), "data/a-0-of-2".to_string()),
            ("data/a-1".to_string(), "data/a-1-of-2".to_string()),
        ];
        dir.rename_files(&renames, &5u32).expect("rename");
        let paths: Vec<&str> = dir.files().iter().map(|f| f.path.as_str()).collect();
        assert_eq!(paths, ["data/a-0-of-2", "data/a-1-of-2"]);
        dir.write_atomically("data/info", b"{}").expect("write");
        drop(dir);
        // As if the run died with one rename made: the resume puts it back.
        std::fs::rename(root.join("data/a-1-of-2"), root.join("data/a-1")).expect("undo one");
        let (dir, state) =
            DatasetDir::resume::<u32>(&root, &options(1), &["data"]).expect("resume");
        assert_eq!(state, Some(5));
        let paths: Vec<&str> = dir.files().iter().map(|f| f.path.as_str()).collect();
        assert_eq!(paths, ["data/a-0", "data/a-1"]);
        assert_eq!(std::fs::read(root.join("data/a-0")).expect("back"), b"zero");
        assert!(!root.join("data/a-0-of-2").exists() && !root.join("data/info").exists());
        drop(dir);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn counters_fill_chunks_in_order() {
        let mut counter = FileCounter::new(2);
        let taken: Vec<_> = (0..5).map(|_| counter.take()).collect();
        assert_eq!(taken, [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0)]);
    }
}
