//! ROS 2 bag folders: `metadata.yaml` names the storage (sqlite3 or mcap), the files in order
//! (a session split with `--max-bag-size` spans several) and their compression (none, zstd per
//! file or per message). The files are read one after the other as one recording
//! ([`Rosbag2`]); sqlite3 files are read in row order a page at a time (SQLite bundled, the
//! file opened read-only and immutable: nothing is written beside it), with the definitions
//! they carry (`message_definitions`, Jazzy and later) or none (built-in definitions apply).
//!
//! The folder is untrusted: `metadata.yaml` is read up to [`MAX_METADATA_BYTES`], every file it
//! names must be a plain name inside the folder, and a message larger than
//! [`MAX_MESSAGE_BYTES`] is refused before it is read.

use crate::ingest::decode::Wire;
use crate::ingest::mcap::McapRecording;
use crate::ingest::recording::{BagError, Channel, MessageReader, RawMessage};
use std::collections::{BTreeMap, VecDeque};
use std::io::Read;
use std::path::{Path, PathBuf};

/// The largest `metadata.yaml` read.
pub const MAX_METADATA_BYTES: u64 = 16 << 20;

/// The largest message (compressed or not) read from a sqlite3 file.
pub const MAX_MESSAGE_BYTES: i64 = 1 << 30;

/// Rows read per query.
const PAGE_ROWS: i64 = 256;

/// What `metadata.yaml` says.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Metadata {
    storage: String,
    files: Vec<String>,
    compression_format: String,
    compression_mode: String,
}

/// A ROS 2 bag folder being read, its files one after the other. Channel ids are the file's
/// index times 2^16 plus the id in the file.
pub struct Rosbag2 {
    folder: PathBuf,
    metadata: Metadata,
    /// The next file to open.
    next_file: usize,
    current: Option<Box<dyn MessageReader>>,
    channels: BTreeMap<u32, Channel>,
    /// Where zstd-compressed sqlite3 files are decompressed ([`decompressed_sqlite`]).
    scratch: Option<PathBuf>,
}

impl Rosbag2 {
    /// Opens the bag folder `folder` (its `metadata.yaml` read and checked); zstd-compressed
    /// sqlite3 files are refused.
    pub fn open(folder: &Path) -> Result<Rosbag2, BagError> {
        Rosbag2::open_with(folder, None)
    }

    /// [`Rosbag2::open`], decompressing zstd-compressed sqlite3 files into `scratch` as they
    /// are reached ([`decompressed_sqlite`]).
    pub fn open_with(folder: &Path, scratch: Option<PathBuf>) -> Result<Rosbag2, BagError> {
        let path = folder.join("metadata.yaml");
        let damaged = |problem: String| BagError::Damaged {
            path: path.clone(),
            offset: 0,
            problem,
        };
        let mut text = String::new();
        crate::files::open_regular(&path)
            .and_then(|file| file.take(MAX_METADATA_BYTES + 1).read_to_string(&mut text))
            .map_err(|source| BagError::Io {
                path: path.clone(),
                source,
            })?;
        if text.len() as u64 > MAX_METADATA_BYTES {
            return Err(damaged(format!("larger than {MAX_METADATA_BYTES} bytes")));
        }
        let metadata = parse_metadata(&text).map_err(damaged)?;
        if !matches!(metadata.storage.as_str(), "sqlite3" | "mcap") {
            return Err(damaged(format!(
                "storage {:?}: surgvla reads sqlite3 and mcap bags",
                metadata.storage
            )));
        }
        let compressed = !metadata.compression_mode.is_empty()
            && !metadata.compression_mode.eq_ignore_ascii_case("none");
        if compressed && metadata.compression_format != "zstd" {
            return Err(damaged(format!(
                "compression {:?}: surgvla reads uncompressed and zstd bags",
                metadata.compression_format
            )));
        }
        if metadata.files.len() > 1 << 16 {
            return Err(damaged("more than 65536 files".into()));
        }
        for file in &metadata.files {
            let plain = Path::new(file).components().count() == 1
                && matches!(
                    Path::new(file).components().next(),
                    Some(std::path::Component::Normal(_))
                );
            if !plain {
                return Err(damaged(format!(
                    "the file {file:?} is not a plain name inside the bag's folder"
                )));
            }
        }
        Ok(Rosbag2 {
            folder: folder.to_path_buf(),
            metadata,
            next_file: 0,
            current: None,
            channels: BTreeMap::new(),
            scratch,
        })
    }

    /// Opens the next file, if any is left.
    fn open_next(&mut self) -> Result<bool, BagError> {
        let Some(name) = self.metadata.files.get(self.next_file) else {
            return Ok(false);
        };
        let path = self.folder.join(name);
        let mode = self.metadata.compression_mode.to_ascii_lowercase();
        let per_message = mode == "message";
        let reader: Box<dyn MessageReader> = match (self.metadata.storage.as_str(), mode.as_str()) {
            ("mcap", "file") => {
                let file = crate::files::open_regular(&path).map_err(|source| BagError::Io {
                    path: path.clone(),
                    source,
                })?;
                let decoder =
                    zstd::stream::read::Decoder::new(file).map_err(|source| BagError::Io {
                        path: path.clone(),
                        source,
                    })?;
                Box::new(McapRecording::from_reader(&path, Box::new(decoder)))
            }
            ("mcap", _) => Box::new(McapRecording::open(&path)?),
            (_, "file") => match &self.scratch {
                Some(scratch) => Box::new(decompressed_sqlite(&path, scratch, file_limit)?),
                None => {
                    return Err(BagError::Damaged {
                        path,
                        offset: 0,
                        problem: "a zstd-compressed sqlite3 file: decompress the bag first (ros2 bag decompress, or zstd -d and an edited metadata.yaml)".into(),
                    });
                }
            },
            _ => Box::new(Sqlite::open(&path)?),
        };
        self.current = Some(if per_message {
            Box::new(Decompressing {
                inner: reader,
                path,
            })
        } else {
            reader
        });
        self.next_file += 1;
        Ok(true)
    }

    /// Copies the current file's channels seen so far, under their bag-wide ids.
    fn note_channels(&mut self) {
        let Some(current) = &self.current else {
            return;
        };
        let base = (self.next_file as u32 - 1) << 16;
        for (id, channel) in current.channels() {
            self.channels
                .entry(base | (id & 0xffff))
                .or_insert_with(|| channel.clone());
        }
    }
}

impl MessageReader for Rosbag2 {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        loop {
            if let Some(current) = &mut self.current {
                if let Some(mut message) = current.next_message()? {
                    if message.connection > 0xffff {
                        return Err(BagError::Damaged {
                            path: self.folder.join(&self.metadata.files[self.next_file - 1]),
                            offset: 0,
                            problem: format!("a topic id of {}", message.connection),
                        });
                    }
                    message.connection |= (self.next_file as u32 - 1) << 16;
                    if !self.channels.contains_key(&message.connection) {
                        self.note_channels();
                    }
                    return Ok(Some(message));
                }
                self.current = None;
            }
            if !self.open_next()? {
                return Ok(None);
            }
            self.note_channels();
        }
    }

    fn channels(&self) -> &BTreeMap<u32, Channel> {
        &self.channels
    }
}

/// Messages compressed one by one (`compression_mode: MESSAGE`), decompressed as read.
struct Decompressing {
    inner: Box<dyn MessageReader>,
    path: PathBuf,
}

impl MessageReader for Decompressing {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        let Some(mut message) = self.inner.next_message()? else {
            return Ok(None);
        };
        let mut data = Vec::new();
        zstd::stream::read::Decoder::new(message.data.as_slice())
            .and_then(|d| d.take(MAX_MESSAGE_BYTES as u64 + 1).read_to_end(&mut data))
            .map_err(|e| BagError::Damaged {
                path: self.path.clone(),
                offset: 0,
                problem: format!("a zstd message that does not decompress: {e}"),
            })?;
        if data.len() as u64 > MAX_MESSAGE_BYTES as u64 {
            return Err(BagError::Damaged {
                path: self.path.clone(),
                offset: 0,
                problem: format!("a message larger than {MAX_MESSAGE_BYTES} bytes"),
            });
        }
        message.data = data;
        Ok(Some(message))
    }

    fn channels(&self) -> &BTreeMap<u32, Channel> {
        self.inner.channels()
    }
}

/// The most a zstd-compressed sqlite3 file of `compressed` bytes may decompress to: 64 times
/// its size plus 1 GiB (a decompression bomb stops there, naming the file).
fn file_limit(compressed: u64) -> u64 {
    compressed.saturating_mul(64).saturating_add(1 << 30)
}

/// A zstd-compressed sqlite3 file (`compression_mode: file`) opened for SQLite, which reads
/// files only: decompressed into `scratch` (streamed, bounded) under a temporary name, opened,
/// and unlinked at once (the connection keeps reading it), so nothing stays behind; `scratch`
/// is removed again when this made it and it is left empty.
fn decompressed_sqlite(
    path: &Path,
    scratch: &Path,
    limit_of: fn(u64) -> u64,
) -> Result<Sqlite, BagError> {
    let io = |at: &Path| {
        let at = at.to_path_buf();
        move |source| BagError::Io { path: at, source }
    };
    let file = crate::files::open_regular(path).map_err(io(path))?;
    let limit = limit_of(file.metadata().map_err(io(path))?.len());
    let made = !scratch.exists();
    std::fs::create_dir_all(scratch).map_err(io(scratch))?;
    let name = path
        .file_name()
        .map_or("bag".into(), |n| n.to_string_lossy());
    let plain = scratch.join(format!(".surgvla-{}-{name}.partial", std::process::id()));
    let opened = (|| {
        let mut decoder = zstd::stream::read::Decoder::new(file).map_err(io(path))?;
        let mut out = std::fs::File::create(&plain).map_err(io(&plain))?;
        let copied = std::io::copy(&mut (&mut decoder).take(limit + 1), &mut out);
        let copied = copied.map_err(|e| BagError::Damaged {
            path: path.to_path_buf(),
            offset: 0,
            problem: format!("a zstd file that does not decompress: {e}"),
        })?;
        if copied > limit {
            return Err(BagError::Damaged {
                path: path.to_path_buf(),
                offset: 0,
                problem: format!("decompresses to more than {limit} bytes"),
            });
        }
        drop(out);
        match Sqlite::open(&plain) {
            Ok(sqlite) => Ok(Sqlite {
                path: path.to_path_buf(),
                ..sqlite
            }),
            // Name the bag's file, not the decompressed copy.
            Err(BagError::Damaged {
                offset, problem, ..
            }) => Err(BagError::Damaged {
                path: path.to_path_buf(),
                offset,
                problem,
            }),
            Err(other) => Err(other),
        }
    })();
    std::fs::remove_file(&plain).ok();
    if made {
        std::fs::remove_dir(scratch).ok();
    }
    opened
}

/// One sqlite3 file of a bag, read in row order a page at a time.
struct Sqlite {
    path: PathBuf,
    connection: rusqlite::Connection,
    channels: BTreeMap<u32, Channel>,
    /// The last row id read.
    last_id: i64,
    page: VecDeque<RawMessage>,
    done: bool,
}

impl Sqlite {
    fn open(path: &Path) -> Result<Sqlite, BagError> {
        use rusqlite::OpenFlags;
        let uri = format!("file:{}?immutable=1", uri_path(path));
        let flags = OpenFlags::SQLITE_OPEN_READ_ONLY
            | OpenFlags::SQLITE_OPEN_URI
            | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let damaged = |e: rusqlite::Error| BagError::Damaged {
            path: path.to_path_buf(),
            offset: 0,
            problem: format!("not a readable rosbag2 sqlite3 file: {e}"),
        };
        let connection = rusqlite::Connection::open_with_flags(uri, flags).map_err(damaged)?;
        let definitions = definitions(&connection).map_err(damaged)?;
        let mut channels = BTreeMap::new();
        let mut statement = connection
            .prepare("SELECT id, name, type FROM topics ORDER BY id LIMIT 65536")
            .map_err(damaged)?;
        let rows = statement
            .query_map([], |row| {
                Ok((
                    row.get::<_, i64>(0)?,
                    row.get::<_, String>(1)?,
                    row.get::<_, String>(2)?,
                ))
            })
            .map_err(damaged)?;
        for row in rows {
            let (id, topic, type_name) = row.map_err(damaged)?;
            let Ok(id) = u32::try_from(id) else {
                continue;
            };
            let definition = definitions.get(&type_name).cloned();
            channels.insert(
                id,
                Channel {
                    topic,
                    type_name,
                    definition,
                    wire: Wire::Cdr,
                },
            );
        }
        drop(statement);
        Ok(Sqlite {
            path: path.to_path_buf(),
            connection,
            channels,
            last_id: i64::MIN,
            page: VecDeque::new(),
            done: false,
        })
    }

    /// Reads the next page of messages.
    fn read_page(&mut self) -> Result<(), BagError> {
        let damaged = |e: rusqlite::Error| BagError::Damaged {
            path: self.path.clone(),
            offset: 0,
            problem: format!("reading its messages: {e}"),
        };
        let mut statement = self
            .connection
            .prepare(
                "SELECT id, topic_id, timestamp, length(data), \
                 CASE WHEN length(data) <= ?2 THEN data END \
                 FROM messages WHERE id > ?1 ORDER BY id LIMIT ?3",
            )
            .map_err(damaged)?;
        let mut rows = statement
            .query(rusqlite::params![
                self.last_id,
                MAX_MESSAGE_BYTES,
                PAGE_ROWS
            ])
            .map_err(damaged)?;
        let mut read = 0;
        while let Some(row) = rows.next().map_err(damaged)? {
            read += 1;
            let id: i64 = row.get(0).map_err(damaged)?;
            let topic: i64 = row.get(1).map_err(damaged)?;
            let receive_ns: i64 = row.get(2).map_err(damaged)?;
            let len: i64 = row.get(3).map_err(damaged)?;
            let data: Option<Vec<u8>> = row.get(4).map_err(damaged)?;
            let Some(data) = data.filter(|_| len <= MAX_MESSAGE_BYTES) else {
                return Err(BagError::Damaged {
                    path: self.path.clone(),
                    offset: 0,
                    problem: format!("message row {id} holds {len} bytes, more than surgvla reads"),
                });
            };
            self.last_id = id;
            self.page.push_back(RawMessage {
                connection: u32::try_from(topic).unwrap_or(u32::MAX),
                receive_ns,
                data,
            });
        }
        self.done = read < PAGE_ROWS;
        Ok(())
    }
}

impl MessageReader for Sqlite {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        if self.page.is_empty() && !self.done {
            self.read_page()?;
        }
        Ok(self.page.pop_front())
    }

    fn channels(&self) -> &BTreeMap<u32, Channel> {
        &self.channels
    }
}

/// The `ros2msg` definitions a sqlite3 file carries, by type (none before Jazzy).
fn definitions(
    connection: &rusqlite::Connection,
) -> Result<BTreeMap<String, String>, rusqlite::Error> {
    let exists: i64 = connection.query_row(
        "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = 'message_definitions'",
        [],
        |row| row.get(0),
    )?;
    let mut found = BTreeMap::new();
    if exists == 0 {
        return Ok(found);
    }
    let mut statement = connection.prepare(
        "SELECT topic_type, encoded_message_definition FROM message_definitions \
         WHERE encoding = 'ros2msg' AND length(encoded_message_definition) <= 1048576 LIMIT 65536",
    )?;
    let rows = statement.query_map([], |row| {
        Ok((row.get::<_, String>(0)?, row.get::<_, String>(1)?))
    })?;
    for row in rows {
        let (type_name, text) = row?;
        found.insert(type_name, text);
    }
    Ok(found)
}

/// `path` for a SQLite URI: absolute, with every byte but unreserved ones and `/`
/// percent-encoded.
fn uri_path(path: &Path) -> String {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = String::new();
    for &b in absolute.as_os_str().as_encoded_bytes() {
        match b {
            b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' | b'/' => {
                out.push(char::from(b));
            }
            _ => out.push_str(&format!("%{b:02X}")),
        }
    }
    out
}

/// The keys surgvla needs from a `metadata.yaml` (`rosbag2_bagfile_information`): the storage,
/// the files in order, the compression. A small reader of the block layout rosbag2 and rosbags
/// write (a scalar `key: value` per line, the file list as `- name` items below its key).
fn parse_metadata(text: &str) -> Result<Metadata, String> {
    let mut metadata = Metadata {
        storage: String::new(),
        files: Vec::new(),
        compression_format: String::new(),
        compression_mode: String::new(),
    };
    if !text.contains("rosbag2_bagfile_information:") {
        return Err("not a rosbag2 metadata file (no rosbag2_bagfile_information)".into());
    }
    let mut lines = text.lines().peekable();
    let mut found_files = false;
    while let Some(line) = lines.next() {
        let trimmed = line.trim_start();
        let indent = line.len() - trimmed.len();
        let Some((key, value)) = trimmed.split_once(':') else {
            continue;
        };
        let value = unquote(value.trim());
        match key {
            "storage_identifier" => metadata.storage = value,
            "compression_format" => metadata.compression_format = value,
            "compression_mode" => metadata.compression_mode = value,
            "relative_file_paths" if !found_files => {
                found_files = true;
                while let Some(item) = lines.peek() {
                    let rest = item.trim_start();
                    let item_indent = item.len() - rest.len();
                    let Some(name) = rest.strip_prefix("- ").filter(|_| item_indent >= indent)
                    else {
                        break;
                    };
                    metadata.files.push(unquote(name.trim()));
                    lines.next();
                }
            }
            _ => {}
        }
    }
    if metadata.files.is_empty() {
        return Err("no relative_file_paths: the bag names no file".into());
    }
    Ok(metadata)
}

/// A YAML scalar without its quotes ('' and "" are empty).
fn unquote(value: &str) -> String {
    let quoted = value.len() >= 2
        && ((value.starts_with('\'') && value.ends_with('\''))
            || (value.starts_with('"') && value.ends_with('"')));
    if quoted {
        value[1..value.len() - 1].replace("''", "'")
    } else {
        value.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::decode::RosValue;

    #[test]
    fn metadata_as_rosbag2_and_rosbags_write_it() {
        let rosbags = "rosbag2_bagfile_information:\n  compression_format: ''\n  compression_mode: ''\n  files:\n  - duration:\n      nanoseconds: 2\n    path: a.mcap\n  relative_file_paths:\n  - a.mcap\n  - 'b.mcap'\n  storage_identifier: mcap\n  version: 8\n";
        let parsed = parse_metadata(rosbags).expect("parse");
        assert_eq!(parsed.storage, "mcap");
        assert_eq!(parsed.files, ["a.mcap", "b.mcap"]);
        assert_eq!(parsed.compression_mode, "");
        let ros = "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  relative_file_paths:\n    - run_0.db3.zstd\n    - run_1.db3.zstd\n  compression_format: zstd\n  compression_mode: FILE\n";
        let parsed = parse_metadata(ros).expect("parse");
        assert_eq!(parsed.files, ["run_0.db3.zstd", "run_1.db3.zstd"]);
        assert_eq!(
            (parsed.compression_format.as_str(), parsed.storage.as_str()),
            ("zstd", "sqlite3")
        );
        assert!(parse_metadata("version: 5\n").is_err());
    }

    #[test]
    fn a_file_outside_the_folder_is_refused() {
        let folder = std::env::temp_dir().join(format!("surgvla-rosbag2-{}", std::process::id()));
        std::fs::create_dir_all(&folder).expect("folder");
        for name in ["../x.db3", "/etc/passwd", "a/b.db3"] {
            let text = format!(
                "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  relative_file_paths:\n  - {name}\n"
            );
            std::fs::write(folder.join("metadata.yaml"), text).expect("write");
            let error = Rosbag2::open(&folder).err().expect("refused");
            assert!(error.to_string().contains("plain name"), "{error}");
        }
        std::fs::remove_dir_all(folder).ok();
    }

    #[test]
    fn uri_paths_are_percent_encoded() {
        assert!(uri_path(Path::new("/a b/c?d#e%.db3")).ends_with("/a%20b/c%3Fd%23e%25.db3"));
    }

    /// A rosbag2 folder of `files` sqlite3 files, each with `/instruction` messages (no
    /// definitions, as Humble writes them): (folder, the messages' texts in order).
    fn sqlite_bag(name: &str, files: usize) -> (PathBuf, Vec<String>) {
        let folder = std::env::temp_dir().join(format!("surgvla-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&folder).ok();
        std::fs::create_dir_all(&folder).expect("folder");
        let mut texts = Vec::new();
        let mut names = Vec::new();
        for f in 0..files {
            let file = format!("bag_{f}.db3");
            let db = rusqlite::Connection::open(folder.join(&file)).expect("db");
            db.execute_batch(
                "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
                 CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, data BLOB NOT NULL);
                 INSERT INTO topics VALUES (3, '/instruction', 'std_msgs/msg/String', 'cdr', '');",
            )
            .expect("schema");
            for k in 0..300 {
                let text = format!("file {f} message {k}");
                let data = crate::ingest::fixtures::cdr_string(&text);
                db.execute(
                    "INSERT INTO messages (topic_id, timestamp, data) VALUES (3, ?1, ?2)",
                    rusqlite::params![1_000 + k, data],
                )
                .expect("insert");
                texts.push(text);
            }
            names.push(format!("  - {file}"));
        }
        let metadata = format!(
            "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  relative_file_paths:\n{}\n  compression_format: ''\n  compression_mode: ''\n",
            names.join("\n")
        );
        std::fs::write(folder.join("metadata.yaml"), metadata).expect("metadata");
        (folder, texts)
    }

    /// `folder`'s sqlite3 files zstd-compressed whole, as `--compression-mode file` leaves them.
    fn compress_files(folder: &Path) {
        let metadata = std::fs::read_to_string(folder.join("metadata.yaml")).expect("metadata");
        for entry in std::fs::read_dir(folder).expect("list") {
            let path = entry.expect("entry").path();
            if path.extension().is_some_and(|e| e == "db3") {
                let plain = std::fs::read(&path).expect("read");
                let packed = zstd::encode_all(plain.as_slice(), 3).expect("zstd");
                std::fs::write(path.with_extension("db3.zstd"), packed).expect("write");
                std::fs::remove_file(path).expect("remove");
            }
        }
        let metadata = (metadata.replace(".db3", ".db3.zstd"))
            .replace("compression_format: ''", "compression_format: zstd")
            .replace("compression_mode: ''", "compression_mode: FILE");
        std::fs::write(folder.join("metadata.yaml"), metadata).expect("metadata");
    }

    #[test]
    fn zstd_compressed_sqlite3_files_are_read_through_a_scratch_copy_that_does_not_stay() {
        use crate::ingest::recording::Messages;
        let (folder, texts) = sqlite_bag("rosbag2-zstd", 2);
        compress_files(&folder);
        let error = Messages::new(Rosbag2::open(&folder).expect("open")).next();
        let error = error.expect("an item").expect_err("no scratch: refused");
        assert!(
            error.to_string().contains("decompress the bag first"),
            "{error}"
        );
        let scratch = folder.with_extension("out");
        std::fs::remove_dir_all(&scratch).ok();
        let bag = Rosbag2::open_with(&folder, Some(scratch.clone())).expect("open");
        let messages: Vec<RawMessage> = Messages::new(bag).collect::<Result<_, _>>().expect("read");
        assert_eq!(messages.len(), texts.len());
        assert!(!scratch.exists(), "the scratch folder this made is gone");
        // A file that decompresses past its bound is refused, naming it, leaving nothing.
        std::fs::create_dir_all(&scratch).expect("scratch");
        let file = folder.join("bag_0.db3.zstd");
        let error = decompressed_sqlite(&file, &scratch, |_| 1000)
            .err()
            .expect("a bomb");
        assert!(error.to_string().contains("bag_0.db3.zstd"), "{error}");
        assert!(
            error.to_string().contains("more than 1000 bytes"),
            "{error}"
        );
        assert_eq!(std::fs::read_dir(&scratch).expect("list").count(), 0);
        // Bytes that are no zstd, and zstd that is no sqlite3, name the bag's file too.
        std::fs::write(&file, b"not zstd").expect("write");
        let error = decompressed_sqlite(&file, &scratch, file_limit)
            .err()
            .expect("bad");
        assert!(error.to_string().contains("bag_0.db3.zstd"), "{error}");
        let packed = zstd::encode_all(&b"not sqlite"[..], 3).expect("zstd");
        std::fs::write(&file, packed).expect("write");
        let error = decompressed_sqlite(&file, &scratch, file_limit)
            .err()
            .expect("bad");
        assert!(error.to_string().contains("bag_0.db3.zstd"), "{error}");
        assert_eq!(std::fs::read_dir(&scratch).expect("list").count(), 0);
        std::fs::remove_dir_all(folder).ok();
        std::fs::remove_dir_all(scratch).ok();
    }

    #[test]
    fn a_session_split_over_sqlite3_files_reads_as_one_in_order() {
        use crate::ingest::recording::Messages;
        let (folder, texts) = sqlite_bag("rosbag2-split", 2);
        let before: Vec<_> = std::fs::read_dir(&folder).expect("list").collect();
        let mut bag = Messages::new(Rosbag2::open(&folder).expect("open"));
        let messages: Vec<RawMessage> = bag.by_ref().collect::<Result<_, _>>().expect("read");
        assert_eq!(messages.len(), 600, "pages of {PAGE_ROWS} across two files");
        let defs = crate::ingest::builtin::ros2_types().expect("builtin");
        for (message, text) in messages.iter().zip(&texts) {
            let channel = &bag.channels()[&message.connection];
            assert_eq!(channel.topic, "/instruction");
            assert!(channel.definition.is_none(), "no definitions in the file");
            let value = crate::ingest::decode::decode(
                &defs,
                &channel.type_name,
                channel.wire,
                &message.data,
            )
            .expect("decode");
            assert_eq!(
                value.at("data").and_then(RosValue::as_str),
                Some(text.as_str())
            );
        }
        assert_eq!(
            messages[300].connection,
            (1 << 16) | 3,
            "the second file's channel"
        );
        let after: Vec<_> = std::fs::read_dir(&folder).expect("list").collect();
        assert_eq!(
            before.len(),
            after.len(),
            "nothing written beside the files"
        );
        std::fs::remove_dir_all(folder).ok();
    }

    #[test]
    fn damaged_sqlite3_files_are_errors_never_panics() {
        use crate::ingest::recording::Messages;
        let (folder, _) = sqlite_bag("rosbag2-fuzz", 1);
        let file = folder.join("bag_0.db3");
        let good = std::fs::read(&file).expect("read");
        let mut state = 0x51_7cc1_b727_220au64;
        let mut errors = 0;
        for round in 0..60 {
            let bytes = if round == 0 {
                good[..good.len() / 2].to_vec()
            } else {
                crate::ingest::fixtures::corrupted(&good, &mut state, 8)
            };
            std::fs::write(&file, &bytes).expect("write");
            let read: Result<Vec<RawMessage>, BagError> =
                Rosbag2::open(&folder).and_then(|bag| Messages::new(bag).take(1000).collect());
            if let Err(error) = read {
                errors += 1;
                assert!(error.to_string().contains("bag_0.db3"), "{error}");
            }
        }
        assert!(errors > 0, "some damage is noticed");
        std::fs::remove_dir_all(folder).ok();
    }
}
