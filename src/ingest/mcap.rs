//! ROS recordings in MCAP (rosbag2's default storage since Iron, and single `.mcap` files),
//! read as a stream with the `mcap` crate's sans-io linear reader: channels of message encoding
//! `cdr` with `ros2msg` schemas (ROS 2) or `ros1` with `ros1msg` (ROS 1 data in MCAP), their
//! messages in file order. Chunks may be uncompressed, zstd or lz4 (decoded in pure Rust by
//! [`crate::ingest::lz4chunk`]; the crate's own lz4 decoder compiles C).
//!
//! The file is untrusted: records are limited to [`MAX_RECORD_BYTES`] before they are buffered,
//! chunk CRCs are checked, a channel of another encoding is refused when its first message
//! arrives, and a damaged or cut file is an error naming it and the byte reached.

use crate::ingest::decode::Wire;
use crate::ingest::recording::{BagError, Channel, MessageReader, RawMessage};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// The largest record (or chunk, compressed or not) read.
pub const MAX_RECORD_BYTES: usize = 1 << 30;

/// An MCAP file of ROS messages being read.
pub struct McapRecording {
    path: PathBuf,
    file: Box<dyn Read + Send>,
    reader: LinearReader,
    /// Bytes fed to the reader so far.
    offset: u64,
    /// Schema id -> (type name, encoding, definition).
    schemas: BTreeMap<u16, (String, String, String)>,
    channels: BTreeMap<u32, Channel>,
}

impl McapRecording {
    /// Opens the MCAP file at `path`.
    pub fn open(path: &Path) -> Result<McapRecording, BagError> {
        let file = crate::files::open_regular(path).map_err(|source| BagError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(McapRecording::from_reader(path, Box::new(file)))
    }

    /// Reads an MCAP file from `bytes` (a decompressing stream, say), naming `path` in errors.
    pub fn from_reader(path: &Path, file: Box<dyn Read + Send>) -> McapRecording {
        let options = LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        let mut reader = LinearReader::new_with_options(options);
        // Registering a named, non-empty decompressor cannot fail.
        let _ = reader.add_decompressor(crate::ingest::lz4chunk::Lz4Chunks::default());
        McapRecording {
            path: path.to_path_buf(),
            file,
            reader,
            offset: 0,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
        }
    }

    fn damaged(&self, problem: impl Into<String>) -> BagError {
        BagError::Damaged {
            path: self.path.clone(),
            offset: self.offset,
            problem: problem.into(),
        }
    }

    /// A channel's record: its schema's type and definition, and its wire format.
    fn channel(&self, channel: mcap::records::Channel) -> Result<Channel, BagError> {
        let (type_name, encoding, definition) = match self.schemas.get(&channel.schema_id) {
            Some(schema) => schema.clone(),
            None => {
                return Err(self.damaged(format!(
                    "channel {} names schema {}, which no record before it defines",
                    channel.topic, channel.schema_id
                )));
            }
        };
        let wire = match (channel.message_encoding.as_str(), encoding.as_str()) {
            ("cdr", "ros2msg") => Wire::Cdr,
            ("ros1", "ros1msg") => Wire::Ros1,
            (message, schema) => {
                return Err(self.damaged(format!(
                    "channel {} holds {message:?} messages with {schema:?} schemas; surgvla reads ROS's (cdr with ros2msg, ros1 with ros1msg)",
                    channel.topic
                )));
            }
        };
        Ok(Channel {
            topic: channel.topic,
            type_name,
            definition: Some(definition),
            wire,
        })
    }
}

impl MessageReader for McapRecording {
    fn next_message(&mut self) -> Result<Option<RawMessage>, BagError> {
        loop {
            let event = match self.reader.next_event() {
                None => return Ok(None),
                Some(Err(error)) => {
                    return Err(self.damaged(format!("not a readable MCAP: {error}")));
                }
                Some(Ok(event)) => event,
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buffer = self.reader.insert(need);
                    let read = self.file.read(buffer).map_err(|source| BagError::Io {
                        path: self.path.clone(),
                        source,
                    })?;
                    self.reader.notify_read(read);
                    self.offset += read as u64;
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data.to_vec()),
            };
            let record = mcap::parse_record(opcode, &data)
                .map_err(|error| self.damaged(format!("a damaged record: {error}")))?;
            match record {
                mcap::records::Record::Schema { header, data } => {
                    let definition = String::from_utf8(data.into_owned()).map_err(|_| {
                        self.damaged(format!("schema {} is not UTF-8", header.name))
                    })?;
                    self.schemas
                        .insert(header.id, (header.name, header.encoding, definition));
                }
                mcap::records::Record::Channel(channel) => {
                    let id = u32::from(channel.id);
                    if !self.channels.contains_key(&id) {
                        let channel = self.channel(channel)?;
                        self.channels.insert(id, channel);
                    }
                }
                mcap::records::Record::Message { header, data } => {
                    let connection = u32::from(header.channel_id);
                    if !self.channels.contains_key(&connection) {
                        return Err(self.damaged(format!(
                            "a message on channel {connection}, which no record before it defines"
                        )));
                    }
                    let receive_ns = i64::try_from(header.log_time)
                        .map_err(|_| self.damaged("a message log time past the year 2262"))?;
                    return Ok(Some(RawMessage {
                        connection,
                        receive_ns,
                        data: data.into_owned(),
                    }));
                }
                _ => {}
            }
        }
    }
    fn channels(&self) -> &BTreeMap<u32, Channel> {
        &self.channels
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::recording::Messages;

    use crate::ingest::fixtures::{corrupted, mcap_bytes, temp_file};

    /// An MCAP of `messages` (log time ns, CDR bytes) on one `std_msgs/String` channel.
    fn mcap_file(compression: Option<mcap::Compression>, messages: &[(u64, &[u8])]) -> Vec<u8> {
        let channels = [("/instruction", "std_msgs/msg/String", "string data\n")];
        let messages: Vec<(usize, u64, Vec<u8>)> =
            messages.iter().map(|(t, d)| (0, *t, d.to_vec())).collect();
        mcap_bytes(compression, &channels, &messages)
    }

    fn write(name: &str, bytes: &[u8]) -> PathBuf {
        temp_file(&format!("mcap-{name}.mcap"), bytes)
    }

    const HELLO: &[u8] = b"\x00\x01\x00\x00\x06\x00\x00\x00hello\x00";

    #[test]
    fn ros2_messages_in_order_with_their_definitions() {
        for compression in [None, Some(mcap::Compression::Zstd)] {
            let path = write("read", &mcap_file(compression, &[(5, HELLO), (7, HELLO)]));
            let mut recording = Messages::new(McapRecording::open(&path).expect("open"));
            let messages: Vec<RawMessage> =
                recording.by_ref().collect::<Result<_, _>>().expect("read");
            assert_eq!(messages.len(), 2);
            assert_eq!((messages[0].receive_ns, messages[1].receive_ns), (5, 7));
            let channel = &recording.channels()[&messages[0].connection];
            assert_eq!(channel.topic, "/instruction");
            assert_eq!(channel.type_name, "std_msgs/msg/String");
            assert_eq!(channel.wire, Wire::Cdr);
            let defs = crate::ingest::msgdef::MessageDefs::parse(
                &channel.type_name,
                channel.definition.as_deref().expect("a definition"),
            )
            .expect("defs");
            let value = crate::ingest::decode::decode(
                &defs,
                "std_msgs/String",
                channel.wire,
                &messages[0].data,
            )
            .expect("decode");
            assert_eq!(value.at("data").and_then(|v| v.as_str()), Some("hello"));
            std::fs::remove_file(path).ok();
        }
    }

    #[test]
    fn cut_and_corrupted_files_are_errors_never_panics() {
        let good = mcap_file(Some(mcap::Compression::Zstd), &[(5, HELLO), (7, HELLO)]);
        let path = write("cut", &good);
        std::fs::write(&path, &good[..good.len() / 2]).expect("write");
        let error = Messages::new(McapRecording::open(&path).expect("open"))
            .find_map(Result::err)
            .expect("an error");
        assert!(error.to_string().contains("byte"), "{error}");
        let mut state = 0x1234_5678_9abc_def1u64;
        for _ in 0..300 {
            std::fs::write(&path, corrupted(&good, &mut state, 3)).expect("write");
            if let Ok(recording) = McapRecording::open(&path) {
                assert!(Messages::new(recording).take(100).count() <= 100);
            }
        }
        std::fs::remove_file(path).ok();
    }
}
