//! What `edit` keeps of a LeRobot dataset besides its episodes: the options that write a
//! dataset like it ([`options_like`]: its layout, codec and file sizes) and the files another
//! tool wrote beside the data that the writer does not make ([`carried_files`]: a community's
//! README in `meta/`, a hub's `.gitattributes`), copied as they are.

use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::lerobot::options::{LeRobotOptions, LeRobotVersion, VideoOptions};
use crate::media::video::Codec;
use std::path::Path;

/// At most this many files are carried over.
const MAX_CARRIED_FILES: usize = 256;

/// A carried file may be at most this large (bytes).
const MAX_CARRIED_BYTES: u64 = 64 << 20;

/// Folders the writer makes whole: what they hold is the data, rewritten by every edit.
const WRITTEN_FOLDERS: &[&str] = &["data", "videos", "images", "meta/episodes"];

/// Files the writer makes (v3.0 and v2.1), and surgvla's own sidecars.
const WRITTEN_FILES: &[&str] = &[
    "README.md",
    "meta/info.json",
    "meta/stats.json",
    "meta/tasks.parquet",
    "meta/tasks.jsonl",
    "meta/episodes.jsonl",
    "meta/episodes_stats.jsonl",
    "meta/surgvla.json",
    "meta/surgvla_manifest.json",
    crate::export::merge::REPORT,
];

/// The options that write a dataset like the one at `root` (of `info`): its layout version,
/// file sizes and chunking from info.json, its video in the codec it has (copied; an episode
/// that must be encoded again gets the codec's default quality).
pub(crate) fn options_like(root: &Path, info: &DatasetInfo) -> Result<LeRobotOptions, ExportError> {
    let json = super::read::read_info(&root.join("meta/info.json"))?;
    let video = info
        .features
        .iter()
        .find_map(|f| f.video)
        .map(|codec: Codec| VideoOptions {
            codec,
            quality: codec.default_quality(),
            file_size_mb: json
                .video_files_size_in_mb
                .unwrap_or(VideoOptions::default().file_size_mb),
        });
    Ok(LeRobotOptions {
        video,
        version: if json.is_v21() {
            LeRobotVersion::V21
        } else {
            LeRobotVersion::V30
        },
        data_file_size_mb: json.data_files_size_in_mb.unwrap_or(100).max(1),
        chunks_size: json.chunks_size.unwrap_or(1000).max(1),
        ..LeRobotOptions::default()
    })
}

/// The regular files under `root` that the writer does not make (see the module overview),
/// as (relative path, bytes), in path order. Hidden files (a run's marker and journals, git's)
/// and symbolic links are passed over; more than [`MAX_CARRIED_FILES`] files, or one over
/// [`MAX_CARRIED_BYTES`], is refused by name.
pub(crate) fn carried_files(root: &Path) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
    let mut found = Vec::new();
    walk(root, "", 0, &mut found)?;
    found.sort();
    let mut carried = Vec::with_capacity(found.len());
    for relative in found {
        let path = root.join(&relative);
        let bytes = crate::export::bounded::read_capped(&path, MAX_CARRIED_BYTES)?;
        carried.push((relative, bytes));
    }
    Ok(carried)
}

/// Gathers the carried files' relative paths under `folder` (`prefix` its own, `depth` deep).
fn walk(
    root: &Path,
    prefix: &str,
    depth: usize,
    found: &mut Vec<String>,
) -> Result<(), ExportError> {
    let folder = root.join(prefix);
    let unreadable = |source| ExportError::Unreadable {
        path: folder.clone(),
        source,
    };
    for entry in std::fs::read_dir(&folder).map_err(unreadable)? {
        let entry = entry.map_err(unreadable)?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || crate::export::paths::component(&name).is_err() {
            continue;
        }
        let relative = if prefix.is_empty() {
            name
        } else {
            format!("{prefix}/{name}")
        };
        let kind = entry.file_type().map_err(unreadable)?;
        if kind.is_dir() && depth < 4 && !WRITTEN_FOLDERS.contains(&relative.as_str()) {
            walk(root, &relative, depth + 1, found)?;
        } else if kind.is_file() && !WRITTEN_FILES.contains(&relative.as_str()) {
            if found.len() == MAX_CARRIED_FILES {
                return Err(ExportError::InvalidDataset {
                    path: root.to_path_buf(),
                    problem: format!(
                        "holds more than {MAX_CARRIED_FILES} files besides its data and metadata; edit carries at most that many"
                    ),
                });
            }
            found.push(relative);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_the_writer_does_not_make_are_carried_and_the_rest_left() {
        let root = std::env::temp_dir().join(format!("surgvla-carry-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        for folder in [
            "meta/episodes/chunk-000",
            "data/chunk-000",
            "meta/sync",
            "notes",
        ] {
            std::fs::create_dir_all(root.join(folder)).unwrap();
        }
        for (file, text) in [
            ("meta/info.json", "{}"),
            ("meta/episodes/chunk-000/file-000.parquet", "x"),
            ("data/chunk-000/file-000.parquet", "x"),
            ("README.md", "card"),
            (".gitattributes", "hidden"),
            ("meta/README.md", "open-h"),
            ("meta/sync/a.json", "{}"),
            ("notes/x.txt", "kept"),
        ] {
            std::fs::write(root.join(file), text).unwrap();
        }
        let carried = carried_files(&root).unwrap();
        let names: Vec<&str> = carried.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["meta/README.md", "meta/sync/a.json", "notes/x.txt"]);
        assert_eq!(carried[0].1, b"open-h");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
