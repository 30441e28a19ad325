//! Which dataset a conversion reads: an identity recorded when `convert` starts and compared
//! when it resumes, so that a resume never mixes the episodes of two inputs (two datasets
//! another tool wrote with the same features look alike in everything else).
//!
//! The identity is a CRC-32C over every file's relative path and size, and over the content of
//! the metadata files (`*.json`, `*.jsonl`: a surgvla manifest, which lists every file's CRC,
//! is one of them). Data files are not read whole: a dataset of terabytes is identified in the
//! time it takes to list it. Folders reached through links are not entered (links to files, as
//! in a Hugging Face hub snapshot, are followed).

use crate::export::bounded;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;
use std::path::Path;

/// The most files listed for an identity.
const MAX_FILES: usize = 1_000_000;

/// The identity of the dataset at `root`: "N files, B bytes, crc32c XXXXXXXX".
pub fn of(root: &Path) -> Result<String, ExportError> {
    let mut files = Vec::new();
    let mut pending = vec![root.to_path_buf()];
    while let Some(dir) = pending.pop() {
        let entries = std::fs::read_dir(&dir).map_err(ExportError::io(&dir))?;
        for entry in entries {
            let entry = entry.map_err(ExportError::io(&dir))?;
            let path = entry.path();
            let kind = entry.file_type().map_err(ExportError::io(&path))?;
            if kind.is_dir() {
                pending.push(path);
            } else if !kind.is_symlink() || path.is_file() {
                files.push(path);
            }
            if files.len() > MAX_FILES {
                return Err(ExportError::InvalidDataset {
                    path: root.to_path_buf(),
                    problem: format!("holds more than {MAX_FILES} files"),
                });
            }
        }
    }
    files.sort();
    let (mut crc, mut total) = (0u32, 0u64);
    for path in &files {
        let relative = path.strip_prefix(root).unwrap_or(path).to_string_lossy();
        let size = std::fs::metadata(path)
            .map_err(ExportError::io(path))?
            .len();
        total += size;
        crc = crc32c::crc32c_append(crc, format!("{relative}\0{size}\0").as_bytes());
        let metadata = path
            .extension()
            .is_some_and(|e| e == "json" || e == "jsonl");
        if metadata {
            // Streamed (a v2.1 `episodes_stats.jsonl` of a large dataset may be gigabytes).
            let (_, content) = crate::export::dir::checksum(bounded::open_regular(path)?, path)?;
            crc = crc32c::crc32c_append(crc, &content.to_le_bytes());
        }
    }
    Ok(format!(
        "{} files, {total} bytes, crc32c {crc:08x}",
        files.len()
    ))
}

/// A source whose info carries the identity of the dataset it reads
/// ([`DatasetInfo::input`]).
pub struct Identified {
    inner: Box<dyn EpisodeSource + Send>,
    info: DatasetInfo,
}

impl Identified {
    /// `inner`, reading the dataset at `root`, with that dataset's identity.
    pub fn new(inner: Box<dyn EpisodeSource + Send>, root: &Path) -> Result<Self, ExportError> {
        let mut info = inner.info().clone();
        info.input = Some(of(root)?);
        Ok(Identified { inner, info })
    }
}
impl Iterator for Identified {
    type Item = Result<crate::episode::Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.inner.next()
    }
}

impl EpisodeSource for Identified {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.inner.skip_episode()
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.inner.drop_stored(unused);
    }

    fn leave_rows_stored(&mut self) {
        self.inner.leave_rows_stored();
    }

    fn taking_only(&mut self, episodes: std::sync::Arc<std::collections::BTreeSet<u64>>) {
        self.inner.taking_only(episodes);
    }

    fn skim(&mut self) -> Option<Result<crate::export::source::Skimmed, ExportError>> {
        self.inner.skim()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_identity_follows_metadata_content_and_data_sizes() {
        let root = std::env::temp_dir().join(format!("surgvla-identity-{}", std::process::id()));
        std::fs::create_dir_all(root.join("data")).unwrap();
        std::fs::write(root.join("info.json"), b"{\"a\": 1}").unwrap();
        std::fs::write(root.join("data/x.parquet"), b"1234").unwrap();
        let first = of(&root).unwrap();
        assert!(first.starts_with("2 files, 12 bytes"), "{first}");
        assert_eq!(of(&root).unwrap(), first);
        std::fs::write(root.join("info.json"), b"{\"a\": 2}").unwrap();
        let second = of(&root).unwrap();
        assert_ne!(second, first, "metadata content counts");
        std::fs::write(root.join("data/x.parquet"), b"12345").unwrap();
        assert_ne!(of(&root).unwrap(), second, "data sizes count");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
