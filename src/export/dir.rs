//! The one owner of a dataset folder, for every format.
//!
//! - **Marker.** [`DatasetDir::create`] refuses a folder that holds anything and writes
//!   [`INCOMPLETE_MARKER`] first; [`DatasetDir::complete`] removes it last, after the format wrote
//!   the file that makes its dataset loadable. A dataset with the marker is never complete.
//! - **Temporary names.** Every file is written under `.name.partial` ([`temporary_name`]) and
//!   renamed when complete ([`DatasetDir::write_atomically`], [`PendingFile::commit`]), so a
//!   crash never leaves a half-written file under its final name.
//! - **Checkpoints and resume.** At a moment when every file written so far is complete, a
//!   format saves its state ([`DatasetDir::save_checkpoint`]); [`DatasetDir::resume`] reopens an
//!   interrupted folder, and [`DatasetDir::remove_files_except`] deletes whatever was written
//!   after the checkpoint.
//! - **Rolling.** [`FileCounter`] numbers rolled files `chunk/file` the LeRobot way.

use crate::export::ExportError;
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::collections::HashSet;
use std::fs::File;
use std::path::{Path, PathBuf};

/// Name of the marker that exists while a dataset is being written.
pub const INCOMPLETE_MARKER: &str = ".surgvla-incomplete";
/// The checkpoint a format saves whenever every file it wrote so far is complete.
pub const CHECKPOINT: &str = "meta/.surgvla-checkpoint.json";

/// The temporary name of `path` while it is being written (`.name.partial`).
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.partial"))
}

/// Writes `bytes` to `path` through a temporary name and a rename; returns the size.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<u64, ExportError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
    }
    let temporary = temporary_name(path);
    std::fs::write(&temporary, bytes).map_err(ExportError::io(&temporary))?;
    std::fs::rename(&temporary, path).map_err(ExportError::io(path))?;
    Ok(bytes.len() as u64)
}

/// A dataset folder being written.
#[derive(Clone, Debug)]
pub struct DatasetDir {
    root: PathBuf,
}

impl DatasetDir {
    /// Starts a dataset in `root`, which must not exist or be empty; writes the marker.
    pub fn create(root: &Path) -> Result<Self, ExportError> {
        let output = |source| ExportError::Output {
            path: root.to_path_buf(),
            source,
        };
        if root.exists() {
            let mut entries = std::fs::read_dir(root).map_err(output)?;
            if entries.next().is_some() {
                return Err(ExportError::NotEmpty {
                    path: root.to_path_buf(),
                });
            }
        }
        std::fs::create_dir_all(root).map_err(output)?;
        let marker = root.join(INCOMPLETE_MARKER);
        std::fs::write(
            &marker,
            b"surgvla is writing this dataset; it is not complete\n",
        )
        .map_err(|source| ExportError::Output {
            path: marker.clone(),
            source,
        })?;
        Ok(DatasetDir {
            root: root.to_path_buf(),
        })
    }

    /// Whether `root` holds an interrupted dataset (one with the marker).
    pub fn is_interrupted(root: &Path) -> bool {
        root.join(INCOMPLETE_MARKER).exists()
    }

    /// Reopens an interrupted dataset (one with the marker).
    pub fn resume(root: &Path) -> Result<Self, ExportError> {
        if !Self::is_interrupted(root) {
            return Err(ExportError::NotResumable {
                path: root.to_path_buf(),
                reason: "it is not an interrupted surgvla dataset (no .surgvla-incomplete marker)"
                    .into(),
            });
        }
        Ok(DatasetDir {
            root: root.to_path_buf(),
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The path of `relative` inside the dataset.
    pub fn path(&self, relative: &str) -> PathBuf {
        self.root.join(relative)
    }

    /// `path` relative to the root, with `/` separators.
    pub fn relative(&self, path: &Path) -> String {
        path.strip_prefix(&self.root)
            .unwrap_or(path)
            .to_string_lossy()
            .into_owned()
    }

    /// Writes a whole file under a temporary name and renames it; returns its size.
    pub fn write_atomically(&self, relative: &str, bytes: &[u8]) -> Result<u64, ExportError> {
        write_atomically(&self.path(relative), bytes)
    }

    /// Opens `relative` for writing under its temporary name (folders created).
    pub fn create_file(&self, relative: &str) -> Result<(File, PendingFile), ExportError> {
        let path = self.path(relative);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
        }
        let temporary = temporary_name(&path);
        let file = File::create(&temporary).map_err(ExportError::io(&temporary))?;
        Ok((file, PendingFile { path, temporary }))
    }

    /// Records a format's state at a moment when every file it wrote is complete.
    pub fn save_checkpoint<T: Serialize>(&self, state: &T) -> Result<(), ExportError> {
        let text = serde_json::to_vec(state).map_err(|source| ExportError::Json {
            path: self.path(CHECKPOINT),
            source,
        })?;
        self.write_atomically(CHECKPOINT, &text).map(|_| ())
    }

    /// The last checkpoint, if one was saved.
    pub fn load_checkpoint<T: DeserializeOwned>(&self) -> Result<Option<T>, ExportError> {
        let path = self.path(CHECKPOINT);
        match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map(Some).map_err(|source| {
                ExportError::NotResumable {
                    path: path.clone(),
                    reason: format!("unreadable checkpoint ({source})"),
                }
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(ExportError::Io { path, source }),
        }
    }

    /// Deletes every file under `folders` whose relative path is not in `keep` (what was written
    /// after the last checkpoint, including temporary files).
    pub fn remove_files_except(
        &self,
        folders: &[&str],
        keep: &HashSet<String>,
    ) -> Result<(), ExportError> {
        for folder in folders {
            let mut pending = vec![self.path(folder)];
            while let Some(dir) = pending.pop() {
                let Ok(entries) = std::fs::read_dir(&dir) else {
                    continue;
                };
                for entry in entries {
                    let path = entry.map_err(ExportError::io(&dir))?.path();
                    if path.is_dir() {
                        pending.push(path);
                    } else if !keep.contains(&self.relative(&path)) {
                        std::fs::remove_file(&path).map_err(ExportError::io(&path))?;
                    }
                }
            }
        }
        Ok(())
    }

    /// Marks the dataset complete: removes the checkpoint, then the marker. Call it after the
    /// format's last file is in place; calling it again does nothing.
    pub fn complete(&self) -> Result<(), ExportError> {
        for relative in [CHECKPOINT, INCOMPLETE_MARKER] {
            let path = self.path(relative);
            match std::fs::remove_file(&path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => return Err(ExportError::Io { path, source }),
            }
        }
        Ok(())
    }
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

    /// Gives the (closed) file its final name; returns its size.
    pub fn commit(self) -> Result<u64, ExportError> {
        std::fs::rename(&self.temporary, &self.path).map_err(ExportError::io(&self.path))?;
        Ok(std::fs::metadata(&self.path).map_or(0, |m| m.len()))
    }
}

/// Numbers rolled files: `chunks_size` files to a chunk folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
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

    #[test]
    fn a_folder_is_incomplete_until_completed_and_refused_when_not_empty() {
        let root = scratch("marker");
        let dir = DatasetDir::create(&root).expect("create");
        assert!(DatasetDir::is_interrupted(&root));
        assert!(matches!(
            DatasetDir::create(&root),
            Err(ExportError::NotEmpty { .. })
        ));
        dir.write_atomically("meta/a.json", b"{}").expect("write");
        assert!(!temporary_name(&root.join("meta/a.json")).exists());
        dir.save_checkpoint(&vec![1u32, 2]).expect("checkpoint");
        let resumed = DatasetDir::resume(&root).expect("resume");
        assert_eq!(
            resumed.load_checkpoint::<Vec<u32>>().expect("load"),
            Some(vec![1, 2])
        );
        resumed.complete().expect("complete");
        resumed.complete().expect("complete twice");
        assert!(!DatasetDir::is_interrupted(&root));
        assert!(!root.join(CHECKPOINT).exists());
        assert!(DatasetDir::resume(&root).is_err());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn files_not_kept_are_removed_and_pending_files_commit() {
        let root = scratch("prune");
        let dir = DatasetDir::create(&root).expect("create");
        let (mut file, pending) = dir
            .create_file("data/chunk-000/file-000.bin")
            .expect("open");
        std::io::Write::write_all(&mut file, b"abc").expect("write");
        drop(file);
        assert_eq!(pending.bytes_so_far(), 3);
        assert!(!root.join("data/chunk-000/file-000.bin").exists());
        assert_eq!(pending.commit().expect("commit"), 3);
        dir.write_atomically("data/chunk-000/file-001.bin", b"x")
            .expect("write");
        let keep = HashSet::from(["data/chunk-000/file-000.bin".to_string()]);
        dir.remove_files_except(&["data", "videos"], &keep)
            .expect("prune");
        assert!(root.join("data/chunk-000/file-000.bin").exists());
        assert!(!root.join("data/chunk-000/file-001.bin").exists());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn counters_fill_chunks_in_order() {
        let mut counter = FileCounter::new(2);
        let taken: Vec<_> = (0..5).map(|_| counter.take()).collect();
        assert_eq!(taken, [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0)]);
    }
}
