//! The first pass over a recording: each mapped topic's message times, in recording order,
//! for the synchronisation rule ([`crate::ingest::sync`]). Only each message's first field (its
//! header) is decoded; messages are not kept. A message's time is its `header.stamp`
//! ([`Clock::Header`]) or the time the recorder received it ([`Clock::Receive`], for stamps that
//! are zero or on another clock), plus the topic's offset (`--time-offset`).

use crate::ingest::decode::{RosValue, decode, decode_first_field};
use crate::ingest::error::IngestError;
use crate::ingest::msgdef::MessageDefs;
use crate::ingest::open::{BagInput, Recording};
use crate::ingest::recording::Channel;
use crate::ingest::sync::{StreamKind, StreamStamps};
use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::path::Path;

/// Which time a message is put on the grid by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Clock {
    /// Its `header.stamp` (when it was measured).
    #[default]
    Header,
    /// When the recorder received it.
    Receive,
}

/// A topic to synchronise.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicSpec {
    pub topic: String,
    pub kind: StreamKind,
    /// Added to every time of the topic (`--time-offset TOPIC=MS`), ns.
    pub offset_ns: i64,
}

/// What the first pass learned: per topic (in the order given) its stamps and its channel
/// (None for a topic the recording does not have).
#[derive(Clone, Debug, PartialEq)]
pub struct FirstPass {
    pub streams: Vec<StreamStamps>,
    pub channels: Vec<Option<Channel>>,
    /// Per topic kept ([`first_pass_keeping`]), its first message decoded whole (None: the
    /// recording has none).
    pub first_messages: Vec<Option<RosValue>>,
}

/// The definitions a channel's messages decode by: its own, else (none, or an empty schema) the
/// built-in ones.
pub fn definitions(
    path: &Path,
    channel: &Channel,
    builtin: &MessageDefs,
) -> Result<MessageDefs, IngestError> {
    let error = |source| IngestError::Definition {
        path: path.to_path_buf(),
        topic: channel.topic.clone(),
        type_name: channel.type_name.clone(),
        source: Box::new(source),
    };
    match channel
        .definition
        .as_deref()
        .filter(|text| !text.trim().is_empty())
    {
        Some(text) => MessageDefs::parse(&channel.type_name, text).map_err(error),
        None => {
            let name = crate::ingest::msgdef::full_name(&channel.type_name, "");
            builtin.check(&name).map_err(error)?;
            Ok(builtin.clone())
        }
    }
}

/// What a channel's messages decode by: its topic's slot among those asked for, its
/// definitions and the channel itself.
pub(crate) struct Decoder {
    pub slot: usize,
    pub defs: MessageDefs,
    pub channel: Channel,
}

/// Each channel's [`Decoder`], settled on its first message, for both passes; a channel whose
/// topic was not asked for is remembered as such (looked up once).
pub(crate) struct Decoders<'t> {
    slot_of: HashMap<&'t str, usize>,
    by_channel: HashMap<u32, Option<Decoder>>,
}

impl<'t> Decoders<'t> {
    pub(crate) fn new(topics: &'t [TopicSpec]) -> Decoders<'t> {
        Decoders {
            slot_of: (topics.iter().enumerate())
                .map(|(i, t)| (t.topic.as_str(), i))
                .collect(),
            by_channel: HashMap::new(),
        }
    }

    /// The decoder of channel `connection` of `recording` (`path`); None for a topic not asked
    /// for.
    pub(crate) fn get(
        &mut self,
        path: &Path,
        recording: &Recording,
        connection: u32,
        builtin: &MessageDefs,
    ) -> Result<Option<&Decoder>, IngestError> {
        if let Entry::Vacant(entry) = self.by_channel.entry(connection) {
            let decoder = match recording.channels().get(&connection) {
                Some(channel) => match self.slot_of.get(channel.topic.as_str()) {
                    Some(&slot) => Some(Decoder {
                        slot,
                        defs: definitions(path, channel, builtin)?,
                        channel: channel.clone(),
                    }),
                    None => None,
                },
                None => None,
            };
            entry.insert(decoder);
        }
        Ok(self.by_channel.get(&connection).and_then(Option::as_ref))
    }
}

/// Reads `path` once for the times of `topics`' messages.
pub fn first_pass(
    path: &Path,
    topics: &[TopicSpec],
    clock: Clock,
    builtin: &MessageDefs,
) -> Result<FirstPass, IngestError> {
    first_pass_keeping(BagInput::new(path, None), topics, clock, builtin, &[])
}

/// [`first_pass`], also keeping the first message of each topic of `keep` decoded whole
/// (what a recording states once, such as a camera's `CameraInfo`; the rest of its messages
/// are skipped undecoded).
pub fn first_pass_keeping(
    input: BagInput<'_>,
    topics: &[TopicSpec],
    clock: Clock,
    builtin: &MessageDefs,
    keep: &[String],
) -> Result<FirstPass, IngestError> {
    let kept_specs = keep.iter().map(|topic| TopicSpec {
        topic: topic.clone(),
        kind: StreamKind::Event,
        offset_ns: 0,
    });
    let all: Vec<TopicSpec> = topics.iter().cloned().chain(kept_specs).collect();
    let mut first_messages: Vec<Option<RosValue>> = vec![None; keep.len()];
    let mut streams: Vec<StreamStamps> = topics
        .iter()
        .map(|t| StreamStamps {
            topic: t.topic.clone(),
            kind: t.kind,
            stamps_ns: Vec::new(),
        })
        .collect();
    let mut channels: Vec<Option<Channel>> = vec![None; topics.len()];
    let mut decoders = Decoders::new(&all);
    let mut recording = Recording::open(input)?;
    let path = input.path;
    // Not a `for` loop: the recording's channels are looked up while it is read.
    while let Some(message) = recording.next() {
        let message = message?;
        let Some(decoder) = decoders.get(path, &recording, message.connection, builtin)? else {
            continue;
        };
        let (slot, channel) = (decoder.slot, &decoder.channel);
        if let Some(kept) = slot.checked_sub(topics.len()) {
            if first_messages[kept].is_none() {
                let value = decode(
                    &decoder.defs,
                    &channel.type_name,
                    channel.wire,
                    &message.data,
                )
                .map_err(|source| IngestError::decode(path, &channel.topic, 0, source))?;
                first_messages[kept] = Some(value);
            }
            continue;
        }
        match &channels[slot] {
            None => channels[slot] = Some(channel.clone()),
            Some(known) if known.type_name != channel.type_name => {
                return Err(IngestError::TwoTypes {
                    path: path.to_path_buf(),
                    topic: channel.topic.clone(),
                    first: known.type_name.clone(),
                    second: channel.type_name.clone(),
                });
            }
            Some(_) => {}
        }
        let (spec, stream) = (&topics[slot], &mut streams[slot]);
        let index = stream.stamps_ns.len();
        let time_ns = match clock {
            Clock::Receive => message.receive_ns,
            Clock::Header => header_time(path, decoder, index, &message)?,
        };
        stream
            .stamps_ns
            .push(time_ns.saturating_add(spec.offset_ns));
    }
    Ok(FirstPass {
        streams,
        channels,
        first_messages,
    })
}

/// A message's `header.stamp` (the `index`-th of its topic), or when it was received for a
/// type without a header; a zero stamp is an error.
fn header_time(
    path: &Path,
    decoder: &Decoder,
    index: usize,
    message: &crate::ingest::recording::RawMessage,
) -> Result<i64, IngestError> {
    let channel = &decoder.channel;
    let first = decode_first_field(
        &decoder.defs,
        &channel.type_name,
        channel.wire,
        &message.data,
    )
    .map_err(|source| IngestError::decode(path, &channel.topic, index, source))?;
    match header_stamp(first.as_ref()) {
        Stamp::At(stamp) => Ok(stamp),
        // A type without a header (std_msgs/String): when it was received.
        Stamp::NoHeader => Ok(message.receive_ns),
        Stamp::Zero => Err(IngestError::NoStamp {
            path: path.to_path_buf(),
            topic: channel.topic.clone(),
            index,
        }),
    }
}

/// What a message's first field says of its time.
enum Stamp {
    At(i64),
    /// A header whose stamp is zero (or unreadable).
    Zero,
    /// The type has no header first.
    NoHeader,
}

/// A decoded first field's stamp, when it is a header (a message with a `stamp`).
fn header_stamp(first: Option<&RosValue>) -> Stamp {
    match first.and_then(|f| f.field("stamp")) {
        None => Stamp::NoHeader,
        Some(stamp) => match stamp.as_time_ns() {
            Some(ns) if ns != 0 => Stamp::At(ns),
            _ => Stamp::Zero,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::builtin::ros2_types;

    /// A ROS 2 MCAP of `std_msgs/Header`-first messages: (topic, type, stamp ns, log ns).
    fn recording(messages: &[(&str, &str, i64, u64)]) -> std::path::PathBuf {
        use crate::ingest::fixtures::{mcap_bytes, temp_file};
        let header_type = "std_msgs/Header header\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
        let mut channels: Vec<(&str, &str, &str)> = Vec::new();
        let mut written = Vec::new();
        for (topic, type_name, stamp, log) in messages {
            let channel = match channels.iter().position(|(t, _, _)| t == topic) {
                Some(channel) => channel,
                None => {
                    channels.push((topic, type_name, header_type));
                    channels.len() - 1
                }
            };
            let mut data = vec![0, 1, 0, 0];
            data.extend(((stamp / 1_000_000_000) as i32).to_le_bytes());
            data.extend(((stamp % 1_000_000_000) as u32).to_le_bytes());
            data.extend(1u32.to_le_bytes());
            data.push(0);
            written.push((channel, *log, data));
        }
        let name = format!("stamps-{}.mcap", messages.len());
        temp_file(&name, &mcap_bytes(None, &channels, &written))
    }

    fn spec(topic: &str, kind: StreamKind, offset_ns: i64) -> TopicSpec {
        TopicSpec {
            topic: topic.into(),
            kind,
            offset_ns,
        }
    }

    #[test]
    fn stamps_by_header_or_receive_time_with_offsets() {
        let path = recording(&[
            ("/cam", "sensor_msgs/msg/Image", 1_000, 50),
            ("/other", "std_msgs/msg/String", 7, 60),
            ("/arm", "geometry_msgs/msg/PoseStamped", 2_000, 70),
            ("/cam", "sensor_msgs/msg/Image", 1_500_000_000, 80),
        ]);
        let topics = [
            spec("/cam", StreamKind::Sampled, 0),
            spec("/arm", StreamKind::Sampled, -500),
            spec("/missing", StreamKind::Event, 0),
        ];
        let builtin = ros2_types().expect("builtin");
        let header = first_pass(&path, &topics, Clock::Header, &builtin).expect("pass");
        let stamps: Vec<&[i64]> = header.streams.iter().map(|s| &s.stamps_ns[..]).collect();
        assert_eq!(stamps, [&[1_000, 1_500_000_000][..], &[1_500], &[]]);
        assert!(header.channels[2].is_none());
        assert_eq!(
            header.channels[0].as_ref().map(|c| c.type_name.as_str()),
            Some("sensor_msgs/msg/Image")
        );
        let receive = first_pass(&path, &topics, Clock::Receive, &builtin).expect("pass");
        assert_eq!(receive.streams[0].stamps_ns, [50, 80]);
        assert_eq!(receive.streams[1].stamps_ns, [-430]);
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn a_zero_stamp_asks_for_the_receive_clock() {
        let path = recording(&[("/cam", "sensor_msgs/msg/Image", 0, 50)]);
        let topics = [spec("/cam", StreamKind::Sampled, 0)];
        let builtin = ros2_types().expect("builtin");
        let error = first_pass(&path, &topics, Clock::Header, &builtin).expect_err("zero");
        assert!(error.to_string().contains("--clock receive"), "{error}");
        assert!(first_pass(&path, &topics, Clock::Receive, &builtin).is_ok());
        std::fs::remove_file(path).ok();
    }
}
