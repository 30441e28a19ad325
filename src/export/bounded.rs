//! Bounded reading of a dataset's files, which may be another tool's or an attacker's: only
//! regular files are read (a metadata file linked to `/dev/zero` or a FIFO would never end),
//! single-document files up to a size cap, line-based files (`*.jsonl`) one capped line at a
//! time. The caps are far above any real file: LeRobot's `info.json` and `stats.json`, TFDS's
//! `dataset_info.json` and `features.json` and our own metadata are kilobytes to a few
//! megabytes.

use crate::export::error::ExportError;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

/// The largest single-document metadata file read (JSON parsed whole into memory).
pub const MAX_METADATA_BYTES: u64 = 32 << 20;
/// The longest line of a JSON-lines file.
pub const MAX_LINE_BYTES: u64 = 16 << 20;
/// The most values one metadata document or line may hold. Parsed into a generic tree, each
/// costs 32 to about 100 bytes whatever its size in the file (`0,` is two bytes), so a 32 MiB
/// document of zeros would cost gigabytes; at this cap a tree stays under about 200 MB. Real
/// metadata holds at most a few values per 10 bytes (a manifest of 200,000 files is well under).
pub const MAX_JSON_VALUES: u64 = 2_000_000;

/// Opens `path` for reading if it is a regular file (links followed).
/// ([`crate::files::open_regular`]: checked before it is opened, so a FIFO never blocks).
pub fn open_regular(path: &Path) -> Result<File, ExportError> {
    crate::files::open_regular(path).map_err(|error| {
        if error.kind() == std::io::ErrorKind::InvalidInput {
            ExportError::InvalidDataset {
                path: path.to_path_buf(),
                problem: "is not a regular file".into(),
            }
        } else {
            ExportError::io(path)(error)
        }
    })
}

/// The bytes of the regular file `path`, refused when longer than `limit_bytes` (checked while
/// reading, so a file growing meanwhile cannot exceed it either).
pub fn read_capped(path: &Path, limit_bytes: u64) -> Result<Vec<u8>, ExportError> {
    let file = open_regular(path)?;
    let expected = file.metadata().map_or(0, |m| m.len());
    if expected > limit_bytes {
        return Err(too_large(path, limit_bytes));
    }
    let mut bytes = Vec::with_capacity(expected as usize);
    file.take(limit_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(ExportError::io(path))?;
    if bytes.len() as u64 > limit_bytes {
        return Err(too_large(path, limit_bytes));
    }
    Ok(bytes)
}

/// A metadata document's bytes ([`MAX_METADATA_BYTES`], [`MAX_JSON_VALUES`]).
pub fn read_metadata(path: &Path) -> Result<Vec<u8>, ExportError> {
    let bytes = read_capped(path, MAX_METADATA_BYTES)?;
    json_values_problem(&bytes).map_or(Ok(bytes), |problem| {
        Err(ExportError::InvalidDataset {
            path: path.to_path_buf(),
            problem,
        })
    })
}

/// Refuses JSON text holding more than [`MAX_JSON_VALUES`] values, counted in one pass over
/// the bytes before any parser builds them (every `,` `[` `{` outside strings begins a value or
/// entry: an upper bound of values less one). Text that is not JSON passes, for its parser to
/// refuse.
pub fn json_values_problem(bytes: &[u8]) -> Option<String> {
    let (mut values, mut in_string, mut escaped) = (1u64, false, false);
    for &b in bytes {
        if in_string {
            match b {
                _ if escaped => escaped = false,
                b'\\' => escaped = true,
                b'"' => in_string = false,
                _ => {}
            }
        } else {
            match b {
                b'"' => in_string = true,
                b',' | b'[' | b'{' => values += 1,
                _ => {}
            }
        }
    }
    (values > MAX_JSON_VALUES).then(|| {
        format!("holds more than the {MAX_JSON_VALUES} JSON values surgvla reads in one document")
    })
}

fn too_large(path: &Path, limit_bytes: u64) -> ExportError {
    ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: format!("is larger than the {} MiB surgvla reads", limit_bytes >> 20),
    }
}

/// The non-blank lines of the JSON-lines file `path`, one at a time: (line number from 1,
/// text). A line over [`MAX_LINE_BYTES`] or not UTF-8 ends the iteration with an error.
pub fn lines(path: &Path) -> Result<Lines, ExportError> {
    Ok(Lines {
        reader: BufReader::new(open_regular(path)?),
        path: path.to_path_buf(),
        number: 0,
        done: false,
    })
}

/// See [`lines`].
pub struct Lines {
    reader: BufReader<File>,
    path: PathBuf,
    number: usize,
    done: bool,
}

impl Iterator for Lines {
    type Item = Result<(usize, String), ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let mut buffer = Vec::new();
        while !self.done {
            buffer.clear();
            self.number += 1;
            let read = (&mut self.reader)
                .take(MAX_LINE_BYTES + 1)
                .read_until(b'\n', &mut buffer);
            let problem = match read {
                Ok(0) => {
                    self.done = true;
                    return None;
                }
                Ok(_) if buffer.len() as u64 > MAX_LINE_BYTES => {
                    format!(
                        "line {} is longer than {} MiB",
                        self.number,
                        MAX_LINE_BYTES >> 20
                    )
                }
                Ok(_) if json_values_problem(&buffer).is_some() => {
                    format!(
                        "line {} holds more than the {MAX_JSON_VALUES} JSON values surgvla reads",
                        self.number
                    )
                }
                Ok(_) => match String::from_utf8(std::mem::take(&mut buffer)) {
                    Ok(text) if text.trim().is_empty() => continue,
                    Ok(text) => return Some(Ok((self.number, text.trim_end().to_string()))),
                    Err(_) => format!("line {} is not UTF-8", self.number),
                },
                Err(source) => {
                    self.done = true;
                    return Some(Err(ExportError::Io {
                        path: self.path.clone(),
                        source,
                    }));
                }
            };
            self.done = true;
            return Some(Err(ExportError::InvalidDataset {
                path: self.path.clone(),
                problem,
            }));
        }
        None
    }
}

/// Reads a JSON file, naming it in the error.
pub(crate) fn read_json(path: &Path) -> Result<serde_json::Value, ExportError> {
    let bytes = read_metadata(path)?;
    serde_json::from_slice(&bytes).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reading_stops_at_the_cap_and_refuses_what_is_not_a_file() {
        let root = std::env::temp_dir().join(format!("surgvla-bounded-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        let path = root.join("a.json");
        std::fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read_capped(&path, 10).unwrap(), b"0123456789");
        assert!(
            read_capped(&path, 9)
                .unwrap_err()
                .to_string()
                .contains("larger than")
        );
        // A character device reports no length and never ends: refused before reading.
        let error = read_capped(Path::new("/dev/zero"), 10).unwrap_err();
        assert!(error.to_string().contains("not a regular file"), "{error}");
        assert!(read_capped(&root, 10).is_err());
        std::fs::write(&path, b"{\"a\": 1}\n\n  \n{\"b\": 2}\r\n").unwrap();
        let read: Vec<(usize, String)> = lines(&path).unwrap().map(Result::unwrap).collect();
        assert_eq!(
            read,
            [(1, "{\"a\": 1}".to_string()), (4, "{\"b\": 2}".to_string())]
        );
        std::fs::write(&path, [b'a', 0xff, b'\n']).unwrap();
        assert!(lines(&path).unwrap().next().unwrap().is_err());
        // A document of many tiny values: refused before it is parsed, as a line too; the same
        // count of values inside a string is text.
        let zeros = format!("[{}0]", "0,".repeat(MAX_JSON_VALUES as usize));
        std::fs::write(&path, &zeros).unwrap();
        let error = read_metadata(&path).unwrap_err().to_string();
        assert!(error.contains("JSON values"), "{error}");
        assert!(lines(&path).unwrap().next().unwrap().is_err());
        std::fs::write(&path, format!("[\"\\\"{zeros}\"]")).unwrap();
        assert!(read_metadata(&path).is_ok());
        let fewer = format!("[{}0]", "0,".repeat(MAX_JSON_VALUES as usize - 2));
        std::fs::write(&path, &fewer).unwrap();
        assert!(read_metadata(&path).is_ok());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
