//! Fixtures for the ingest modules' tests: MCAP recordings written with the `mcap` crate's own
//! writer, CDR bytes, seeded corruption and decoded values built by hand.

use crate::ingest::decode::RosValue;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// A channel of an MCAP fixture: (topic, type, `ros2msg` schema text; empty: none carried).
pub(crate) type ChannelSpec<'a> = (&'a str, &'a str, &'a str);

/// An MCAP of CDR `messages` (channel index, log time ns, bytes) on `channels`, in the order
/// given.
pub(crate) fn mcap_bytes(
    compression: Option<mcap::Compression>,
    channels: &[ChannelSpec<'_>],
    messages: &[(usize, u64, Vec<u8>)],
) -> Vec<u8> {
    let mut writer = mcap::WriteOptions::new()
        .compression(compression)
        .create(std::io::Cursor::new(Vec::new()))
        .expect("writer");
    let ids: Vec<u16> = channels
        .iter()
        .map(|(topic, type_name, schema)| {
            let schema = writer
                .add_schema(type_name, "ros2msg", schema.as_bytes())
                .expect("schema");
            writer
                .add_channel(schema, topic, "cdr", &BTreeMap::new())
                .expect("channel")
        })
        .collect();
    for (sequence, (channel, time, data)) in messages.iter().enumerate() {
        let header = mcap::records::MessageHeader {
            channel_id: ids[*channel],
            sequence: sequence as u32,
            log_time: *time,
            publish_time: *time,
        };
        writer
            .write_to_known_channel(&header, data)
            .expect("message");
    }
    writer.finish().expect("finish");
    writer.into_inner().into_inner()
}

/// Writes `bytes` to a file of the temporary folder named after `name` and this process.
pub(crate) fn temp_file(name: &str, bytes: &[u8]) -> PathBuf {
    // Each call its own file: tests running at once write and remove theirs.
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let path = std::env::temp_dir().join(format!("surgvla-{call}-{name}-{}", std::process::id()));
    std::fs::write(&path, bytes).expect("write");
    path
}

/// `std_msgs/String` in CDR.
pub(crate) fn cdr_string(text: &str) -> Vec<u8> {
    let mut data = vec![0, 1, 0, 0];
    data.extend((text.len() as u32 + 1).to_le_bytes());
    data.extend(text.as_bytes());
    data.push(0);
    data
}

/// `bytes` with `count` bytes overwritten at places an xorshift generator from `state` picks.
pub(crate) fn corrupted(bytes: &[u8], state: &mut u64, count: usize) -> Vec<u8> {
    let mut bytes = bytes.to_vec();
    for _ in 0..count {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        let i = (*state % bytes.len() as u64) as usize;
        bytes[i] = (*state >> 40) as u8;
    }
    bytes
}

/// A decoded message of `fields`.
pub(crate) fn message(fields: Vec<(&str, RosValue)>) -> RosValue {
    RosValue::Message(
        fields
            .into_iter()
            .map(|(n, v)| (n.to_string(), v))
            .collect(),
    )
}
