//! The first pass over a recording: each mapped topic's message times, in recording order,
//! for the synchronisation rule ([`crate::ingest::sync`]). Only each message's first field (its
//! header) is decoded; messages are not kept. A message's time is its `header.stamp`
//! ([`Clock::Header`]) or the time the recorder received it ([`Clock::Receive`], for stamps that
//! are zero or on another clock), plus the topic's offset (`--time-offset`).

use crate::ingest::decode::{RosValue, decode_first_field};
use crate::ingest::error::IngestError;
use crate::ingest::msgdef::MessageDefs;
use crate::ingest::open::Recording;
use crate::ingest::recording::Channel;
use crate::ingest::sync::{StreamKind, StreamStamps};
use std::collections::BTreeMap;
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

/// Reads `path` once for the times of `topics`' messages.
pub fn first_pass(
    path: &Path,
    topics: &[TopicSpec],
    clock: Clock,
    builtin: &MessageDefs,
) -> Result<FirstPass, IngestError> {
    let slot_of: BTreeMap<&str, usize> = topics
        .iter()
        .enumerate()
        .map(|(i, t)| (t.topic.as_str(), i))
        .collect();
    let mut streams: Vec<StreamStamps> = topics
        .iter()
        .map(|t| StreamStamps {
            topic: t.topic.clone(),
            kind: t.kind,
            stamps_ns: Vec::new(),
        })
        .collect();
    let mut channels: Vec<Option<Channel>> = vec![None; topics.len()];
    // Channel id -> (slot, its definitions).
    let mut decoders: BTreeMap<u32, (usize, MessageDefs)> = BTreeMap::new();
    let mut recording = Recording::open(path)?;
    // Not a `for` loop: the recording's channels are looked up while it is read.
    while let Some(message) = recording.next() {
        let message = message?;
        if let std::collections::btree_map::Entry::Vacant(entry) =
            decoders.entry(message.connection)
        {
            let Some(channel) = recording.channels().get(&message.connection) else {
                continue;
            };
            let Some(&slot) = slot_of.get(channel.topic.as_str()) else {
                continue;
            };
            if let Some(known) = &channels[slot]
                && known.type_name != channel.type_name
            {
                return Err(IngestError::TwoTypes {
                    path: path.to_path_buf(),
                    topic: channel.topic.clone(),
                    first: known.type_name.clone(),
                    second: channel.type_name.clone(),
                });
            }
            let defs = definitions(path, channel, builtin)?;
            channels[slot].get_or_insert_with(|| channel.clone());
            entry.insert((slot, defs));
        }
        let Some((slot, defs)) = decoders.get(&message.connection) else {
            continue;
        };
        let (spec, stream) = (&topics[*slot], &mut streams[*slot]);
        let index = stream.stamps_ns.len();
        let time_ns = match clock {
            Clock::Receive => message.receive_ns,
            Clock::Header => {
                let channel = channels[*slot]
                    .as_ref()
                    .map(|c| (c.type_name.as_str(), c.wire));
                let (type_name, wire) = channel.unwrap_or(("", crate::ingest::decode::Wire::Ros1));
                let first =
                    decode_first_field(defs, type_name, wire, &message.data).map_err(|source| {
                        IngestError::Decode {
                            path: path.to_path_buf(),
                            topic: spec.topic.clone(),
                            index,
                            source: Box::new(source),
                        }
                    })?;
                header_stamp(first.as_ref()).ok_or_else(|| IngestError::NoStamp {
                    path: path.to_path_buf(),
                    topic: spec.topic.clone(),
                    index,
                })?
            }
        };
        stream
            .stamps_ns
            .push(time_ns.saturating_add(spec.offset_ns));
    }
    Ok(FirstPass { streams, channels })
}

/// A decoded `header` field's stamp, when it is one and not zero.
fn header_stamp(first: Option<&RosValue>) -> Option<i64> {
    first?
        .field("stamp")?
        .as_time_ns()
        .filter(|&stamp| stamp != 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::builtin::ros2_types;

    /// A ROS 2 MCAP of `std_msgs/Header`-first messages: (topic, type, stamp ns, log ns).
    fn recording(messages: &[(&str, &str, i64, u64)]) -> std::path::PathBuf {
        let mut writer = mcap::WriteOptions::new()
            .create(std::io::Cursor::new(Vec::new()))
            .expect("writer");
        let header_type = "std_msgs/Header header\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
        let mut channels = BTreeMap::new();
        for (sequence, (topic, type_name, stamp, log)) in messages.iter().enumerate() {
            let channel = *channels.entry(*topic).or_insert_with(|| {
                let schema = writer
                    .add_schema(type_name, "ros2msg", header_type.as_bytes())
                    .expect("schema");
                writer
                    .add_channel(schema, topic, "cdr", &BTreeMap::new())
                    .expect("channel")
            });
            let mut data = vec![0, 1, 0, 0];
            data.extend(((stamp / 1_000_000_000) as i32).to_le_bytes());
            data.extend(((stamp % 1_000_000_000) as u32).to_le_bytes());
            data.extend(1u32.to_le_bytes());
            data.push(0);
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: sequence as u32,
                log_time: *log,
                publish_time: *log,
            };
            writer
                .write_to_known_channel(&header, &data)
                .expect("write");
        }
        writer.finish().expect("finish");
        let path = std::env::temp_dir().join(format!(
            "surgvla-stamps-{}-{}.mcap",
            messages.len(),
            std::process::id()
        ));
        std::fs::write(&path, writer.into_inner().into_inner()).expect("write");
        path
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
