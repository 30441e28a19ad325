//! ROS 1 bags (format 2.0), read as a stream: [`Ros1Bag`] yields every message in the order
//! the bag stores it, with the connection (topic, type, definition) it arrived on.
//!
//! A bag is `#ROSBAG V2.0\n` then records, each `header_len u32 | header | data_len u32 |
//! data`, a header being fields `len u32 | name=value` whose `op` says what the record is: the
//! bag header (0x03), chunks (0x05: `compression` none, bz2 or lz4 and the uncompressed
//! `size`; they hold connection and message records), connections (0x07: `conn`, `topic`; the
//! data another header with `type`, `md5sum`, `message_definition`), messages (0x02: `conn`,
//! `time`), and the index (0x04, 0x06), which is not needed: chunks are read in file order, so a
//! bag whose recording was killed before its index was written reads too, up to its last whole
//! record.
//!
//! Everything is untrusted: a length is checked against the bytes the file (or the chunk) has
//! left before anything is allocated, a chunk decompresses to at most the size it states (and
//! [`MAX_CHUNK_BYTES`]), and a damaged record is an error naming the file and its offset.

use crate::ingest::decode::Wire;
use crate::ingest::recording::{BagError, Channel, MessageReader, RawMessage};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

/// The first bytes of a ROS 1 bag.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
/// The largest chunk (uncompressed) read.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// The largest record header, and connection record's data, read.
pub const MAX_HEADER_BYTES: u64 = 16 << 20;

/// A ROS 1 bag being read (see the module overview).
pub struct Ros1Bag {
    path: PathBuf,
    file: BufReader<File>,
    /// Offset of the next record in the file.
    offset: u64,
    len: u64,
    connections: BTreeMap<u32, Channel>,
    /// The chunk being read: its records and the offset of the next one in it, with the file
    /// offset it started at (for messages).
    chunk: Option<(Vec<u8>, usize, u64)>,
}

impl Ros1Bag {
    /// Opens the bag at `path`: it must begin with [`MAGIC`].
    pub fn open(path: &Path) -> Result<Ros1Bag, BagError> {
        let io = |source| BagError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = crate::files::open_regular(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut file = BufReader::new(file);
        let mut magic = [0u8; MAGIC.len()];
        if len < MAGIC.len() as u64 || file.read_exact(&mut magic).is_err() || magic != MAGIC {
            return Err(BagError::Damaged {
                path: path.to_path_buf(),
                offset: 0,
                problem: "not a ROS 1 bag (format 2.0): it does not begin with #ROSBAG V2.0".into(),
            });
        }
        Ok(Ros1Bag {
            path: path.to_path_buf(),
            file,
            offset: MAGIC.len() as u64,
            len,
            connections: BTreeMap::new(),
            chunk: None,
        })
    }

    fn damaged(&self, offset: u64, problem: impl Into<String>) -> BagError {
        BagError::Damaged {
            path: self.path.clone(),
            offset,
            problem: problem.into(),
        }
    }

    /// `len` bytes of the file from the current offset, checked against what it has left.
    fn read_file(&mut self, len: u64, what: &str) -> Result<Vec<u8>, BagError> {
        if len > self.len.saturating_sub(self.offset) {
            return Err(self.damaged(
                self.offset,
                format!("{what} of {len} bytes runs past the end of the file (cut short?)"),
            ));
        }
        let mut bytes = vec![0u8; len as usize];
        self.file
            .read_exact(&mut bytes)
            .map_err(|source| BagError::Io {
                path: self.path.clone(),
                source,
            })?;
        self.offset += len;
        Ok(bytes)
    }

    fn read_u32(&mut self, what: &str) -> Result<u32, BagError> {
        let bytes = self.read_file(4, what)?;
        Ok(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    }

    /// The next record of the file.
    fn file_record(&mut self) -> Result<Option<FileRecord>, BagError> {
        if self.offset >= self.len {
            return Ok(None);
        }
        let start = self.offset;
        let header_len = self.read_u32("a record's header length")?;
        if u64::from(header_len) > MAX_HEADER_BYTES {
            return Err(self.damaged(start, format!("a record header of {header_len} bytes")));
        }
        let header = self.read_file(u64::from(header_len), "a record header")?;
        let fields = Fields::parse(&header).map_err(|p| self.damaged(start, p))?;
        let data_len = u64::from(self.read_u32("a record's data length")?);
        let op = fields.op().map_err(|p| self.damaged(start, p))?;
        let limit = match op {
            OP_CHUNK | OP_MESSAGE => MAX_CHUNK_BYTES,
            _ => MAX_HEADER_BYTES,
        };
        if data_len > limit {
            return Err(self.damaged(start, format!("a record of {data_len} bytes")));
        }
        let data = self.read_file(data_len, "a record's data")?;
        Ok(Some(FileRecord {
            start,
            op,
            header,
            data,
        }))
    }

    /// The records of a chunk, decompressed.
    fn open_chunk(
        &self,
        start: u64,
        fields: &Fields<'_>,
        data: Vec<u8>,
    ) -> Result<Vec<u8>, BagError> {
        let size = u64::from(fields.u32("size").map_err(|p| self.damaged(start, p))?);
        if size > MAX_CHUNK_BYTES {
            return Err(self.damaged(start, format!("a chunk of {size} bytes")));
        }
        let compression = fields
            .text("compression")
            .map_err(|p| self.damaged(start, p))?;
        let records = match compression.as_str() {
            "none" => Ok(data),
            "bz2" => bounded(bzip2::read::BzDecoder::new(data.as_slice()), size),
            "lz4" => bounded(lz4_flex::frame::FrameDecoder::new(data.as_slice()), size),
            other => {
                return Err(self.damaged(
                    start,
                    format!("chunk compression {other:?} is not none, bz2 or lz4"),
                ));
            }
        }
        .map_err(|p| self.damaged(start, format!("a {compression} chunk {p}")))?;
        if records.len() as u64 != size {
            return Err(self.damaged(
                start,
                format!(
                    "a chunk holds {} bytes where its header says {size}",
                    records.len()
                ),
            ));
        }
        Ok(records)
    }

    /// Records a connection (its data is a header of `type`, `md5sum`, `message_definition`).
    fn connection(&mut self, start: u64, fields: &Fields<'_>, data: &[u8]) -> Result<(), BagError> {
        let id = fields.u32("conn").map_err(|p| self.damaged(start, p))?;
        let topic = fields.text("topic").map_err(|p| self.damaged(start, p))?;
        let details = Fields::parse(data).map_err(|p| self.damaged(start, p))?;
        let text = |name: &str| details.text(name).map_err(|p| self.damaged(start, p));
        let connection = Channel {
            topic,
            type_name: text("type")?,
            definition: Some(text("message_definition")?),
            wire: Wire::Ros1,
        };
        self.connections.entry(id).or_insert(connection);
        Ok(())
    }

    /// The next message record inside the current chunk, if any is left.
    fn chunk_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        while let Some((records, at, chunk_start)) = self.chunk.take() {
            if at >= records.len() {
                continue;
            }
            let (fields, data, next) =
                chunk_record(&records, at).map_err(|p| self.damaged(chunk_start, p))?;
            let message = match fields.op().map_err(|p| self.damaged(chunk_start, p))? {
                OP_CONNECTION => {
                    self.connection(chunk_start, &fields, data)?;
                    None
                }
                OP_MESSAGE => Some(self.message(chunk_start, &fields, data.to_vec())?),
                _ => None,
            };
            self.chunk = Some((records, next, chunk_start));
            if message.is_some() {
                return Ok(message);
            }
        }
        Ok(None)
    }

    fn message(
        &self,
        start: u64,
        fields: &Fields<'_>,
        data: Vec<u8>,
    ) -> Result<RawMessage, BagError> {
        let connection = fields.u32("conn").map_err(|p| self.damaged(start, p))?;
        if !self.connections.contains_key(&connection) {
            return Err(self.damaged(
                start,
                format!("a message on connection {connection}, which no record before it defines"),
            ));
        }
        let time = fields.bytes("time").map_err(|p| self.damaged(start, p))?;
        let [s0, s1, s2, s3, n0, n1, n2, n3] = time[..] else {
            return Err(self.damaged(start, "a message time that is not 8 bytes"));
        };
        let sec = i64::from(u32::from_le_bytes([s0, s1, s2, s3]));
        let nsec = i64::from(u32::from_le_bytes([n0, n1, n2, n3]));
        Ok(RawMessage {
            connection,
            receive_ns: sec * 1_000_000_000 + nsec,
            data,
        })
    }
}

/// A record read from the file (not from a chunk).
struct FileRecord {
    /// Its offset in the file.
    start: u64,
    op: u8,
    /// Its header, checked by [`Fields::parse`].
    header: Vec<u8>,
    data: Vec<u8>,
}

const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// Reads `reader` to its end, refusing more than `size` bytes (a decompression bomb).
fn bounded(reader: impl Read, size: u64) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(size.min(64 << 20) as usize);
    reader
        .take(size + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("does not decompress: {e}"))?;
    Ok(out)
}

/// The record at `at` in a chunk's bytes: its header fields, its data and the next offset.
fn chunk_record(records: &[u8], at: usize) -> Result<(Fields<'_>, &[u8], usize), String> {
    let take = |at: usize, len: usize, what: &str| -> Result<&[u8], String> {
        (at.checked_add(len))
            .and_then(|end| records.get(at..end))
            .ok_or_else(|| format!("{what} at chunk byte {at} runs past the chunk"))
    };
    let u32_at = |at: usize, what: &str| -> Result<usize, String> {
        let b = take(at, 4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let header_len = u32_at(at, "a record's header length")?;
    let header = take(at + 4, header_len, "a record header")?;
    let data_at = at + 4 + header_len;
    let data_len = u32_at(data_at, "a record's data length")?;
    let data = take(data_at + 4, data_len, "a record's data")?;
    Ok((Fields::parse(header)?, data, data_at + 4 + data_len))
}

/// A record header's fields, `name=value` (values are binary), read in place: a header holds
/// a handful of fields, so a lookup walks them (no map per record).
#[derive(Clone, Copy, Debug)]
struct Fields<'a>(&'a [u8]);

impl<'a> Fields<'a> {
    /// Checks that `bytes` is a sequence of length-prefixed `name=value` fields.
    fn parse(bytes: &'a [u8]) -> Result<Fields<'a>, String> {
        let fields = Fields(bytes);
        for field in fields.iter() {
            field?;
        }
        Ok(fields)
    }

    /// Each field's (name, value).
    fn iter(self) -> impl Iterator<Item = Result<(&'a [u8], &'a [u8]), String>> {
        let mut bytes = self.0;
        std::iter::from_fn(move || {
            if bytes.is_empty() {
                return None;
            }
            let Some((len, rest)) = bytes.split_first_chunk::<4>() else {
                bytes = &[];
                return Some(Err("a header field's length is cut short".into()));
            };
            let len = u32::from_le_bytes(*len) as usize;
            let Some(field) = rest.get(..len) else {
                bytes = &[];
                return Some(Err(format!(
                    "a header field of {len} bytes runs past its header"
                )));
            };
            bytes = &rest[len..];
            Some(match field.iter().position(|&b| b == b'=') {
                Some(equals) => Ok((&field[..equals], &field[equals + 1..])),
                None => Err("a header field without '='".into()),
            })
        })
    }

    /// The value of the first field called `name` (a checked header: see [`Fields::parse`]).
    fn bytes(&self, name: &str) -> Result<&'a [u8], String> {
        self.iter()
            .filter_map(Result::ok)
            .find(|(n, _)| *n == name.as_bytes())
            .map(|(_, value)| value)
            .ok_or_else(|| format!("a record without its {name} field"))
    }

    fn op(&self) -> Result<u8, String> {
        match self.bytes("op")? {
            [op] => Ok(*op),
            _ => Err("an op field that is not one byte".into()),
        }
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        match self.bytes(name)? {
            [a, b, c, d] => Ok(u32::from_le_bytes([*a, *b, *c, *d])),
            _ => Err(format!("a {name} field that is not 4 bytes")),
        }
    }

    fn text(&self, name: &str) -> Result<String, String> {
        String::from_utf8(self.bytes(name)?.to_vec())
            .map_err(|_| format!("a {name} field that is not UTF-8"))
    }
}

impl MessageReader for Ros1Bag {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        loop {
            if let Some(message) = self.chunk_message()? {
                return Ok(Some(message));
            }
            let Some(FileRecord {
                start,
                op,
                header,
                data,
            }) = self.file_record()?
            else {
                return Ok(None);
            };
            let fields = Fields(&header);
            match op {
                OP_CHUNK => {
                    let records = self.open_chunk(start, &fields, data)?;
                    self.chunk = Some((records, 0, start));
                }
                OP_CONNECTION => self.connection(start, &fields, &data)?,
                OP_MESSAGE => return self.message(start, &fields, data).map(Some),
                OP_BAG_HEADER | OP_INDEX | OP_CHUNK_INFO => {}
                other => {
                    return Err(self.damaged(start, format!("a record of unknown op {other:#04x}")));
                }
            }
        }
    }
    fn channels(&self) -> &BTreeMap<u32, Channel> {
        &self.connections
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::ingest::recording::Messages;

    /// A header of `fields`.
    fn header(fields: &[(&str, &[u8])]) -> Vec<u8> {
        let mut out = Vec::new();
        for (name, value) in fields {
            let field = [name.as_bytes(), b"=", value].concat();
            out.extend((field.len() as u32).to_le_bytes());
            out.extend(field);
        }
        out
    }

    fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
        let header = header(fields);
        let mut out = (header.len() as u32).to_le_bytes().to_vec();
        out.extend(header);
        out.extend((data.len() as u32).to_le_bytes());
        out.extend(data);
        out
    }

    /// A bag of `messages` (topic index, time ns, data) on two `std_msgs/String`-like topics,
    /// in one chunk of `compression`.
    pub(crate) fn bag(compression: &str, messages: &[(u32, u64, &[u8])]) -> Vec<u8> {
        let mut records = Vec::new();
        for (id, topic) in [(0u32, "/a"), (1, "/b")] {
            let details = header(&[
                ("type", b"std_msgs/String"),
                ("md5sum", b"992ce8a1687cec8c8bd883ec73ca41d1"),
                ("message_definition", b"string data\n"),
            ]);
            records.extend(record(
                &[
                    ("op", &[OP_CONNECTION]),
                    ("conn", &id.to_le_bytes()),
                    ("topic", topic.as_bytes()),
                ],
                &details,
            ));
        }
        for (conn, time_ns, data) in messages {
            let mut time = ((time_ns / 1_000_000_000) as u32).to_le_bytes().to_vec();
            time.extend(((time_ns % 1_000_000_000) as u32).to_le_bytes());
            records.extend(record(
                &[
                    ("op", &[OP_MESSAGE]),
                    ("conn", &conn.to_le_bytes()),
                    ("time", &time),
                ],
                data,
            ));
        }
        let size = (records.len() as u32).to_le_bytes();
        let stored = match compression {
            "none" => records,
            "lz4" => {
                let mut encoder = lz4_flex::frame::FrameEncoder::new(Vec::new());
                std::io::Write::write_all(&mut encoder, &records).expect("lz4");
                encoder.finish().expect("lz4")
            }
            "bz2" => {
                let mut encoder =
                    bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
                std::io::Write::write_all(&mut encoder, &records).expect("bz2");
                encoder.finish().expect("bz2")
            }
            other => panic!("{other}"),
        };
        let mut out = MAGIC.to_vec();
        out.extend(record(
            &[("op", &[OP_BAG_HEADER]), ("index_pos", &0u64.to_le_bytes())],
            &[b' '; 16],
        ));
        out.extend(record(
            &[
                ("op", &[OP_CHUNK]),
                ("compression", compression.as_bytes()),
                ("size", &size),
            ],
            &stored,
        ));
        out
    }

    fn write(name: &str, bytes: &[u8]) -> PathBuf {
        let path =
            std::env::temp_dir().join(format!("surgvla-ros1-{name}-{}.bag", std::process::id()));
        std::fs::write(&path, bytes).expect("write");
        path
    }

    #[test]
    fn every_compression_reads_the_messages_in_order() {
        let messages: [(u32, u64, &[u8]); 3] = [
            (0, 1_500_000_000, b"\x01\0\0\0x"),
            (1, 1_600_000_001, b"\x00\0\0\0"),
            (0, 2_000_000_000, b"\x02\0\0\0yz"),
        ];
        for compression in ["none", "lz4", "bz2"] {
            let path = write(compression, &bag(compression, &messages));
            let mut bag = Messages::new(Ros1Bag::open(&path).expect("open"));
            let read: Vec<RawMessage> = bag.by_ref().collect::<Result<_, _>>().expect("read");
            let got: Vec<(u32, i64, &[u8])> = read
                .iter()
                .map(|m| (m.connection, m.receive_ns, m.data.as_slice()))
                .collect();
            let want: Vec<(u32, i64, &[u8])> = messages
                .iter()
                .map(|(c, t, d)| (*c, *t as i64, *d))
                .collect();
            assert_eq!(got, want, "{compression}");
            assert_eq!(bag.channels()[&1].topic, "/b");
            assert_eq!(
                bag.channels()[&0].definition.as_deref(),
                Some("string data\n")
            );
            std::fs::remove_file(path).ok();
        }
    }

    #[test]
    fn cut_and_damaged_bags_are_errors_naming_file_and_offset() {
        let messages: [(u32, u64, &[u8]); 2] = [(0, 1, b"\x01\0\0\0x"), (1, 2, b"\0\0\0\0")];
        let good = bag("lz4", &messages);
        let path = write("cut", &good);
        for cut in [good.len() - 1, good.len() / 2, MAGIC.len() + 3] {
            std::fs::write(&path, &good[..cut]).expect("write");
            let results: Vec<_> = Messages::new(Ros1Bag::open(&path).expect("open")).collect();
            let error = results.into_iter().find_map(Result::err).expect("an error");
            let text = error.to_string();
            assert!(
                text.contains(&path.display().to_string()) && text.contains("byte"),
                "{text}"
            );
        }
        std::fs::write(&path, b"#ROSBAG V1.2\n").expect("write");
        assert!(Ros1Bag::open(&path).is_err());
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn seeded_corruption_never_panics_or_hangs() {
        let messages: [(u32, u64, &[u8]); 2] = [(0, 1, b"\x01\0\0\0x"), (1, 2, b"\0\0\0\0")];
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for compression in ["none", "lz4", "bz2"] {
            let good = bag(compression, &messages);
            let path = write(&format!("fuzz-{compression}"), &good);
            for _ in 0..300 {
                let bytes = crate::ingest::fixtures::corrupted(&good, &mut state, 3);
                std::fs::write(&path, &bytes).expect("write");
                if let Ok(bag) = Ros1Bag::open(&path) {
                    assert!(Messages::new(bag).take(100).count() <= 100);
                }
            }
            std::fs::remove_file(path).ok();
        }
    }
}
