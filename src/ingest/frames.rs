//! The second pass over a recording: the messages the synchronisation plan picked, decoded,
//! handed over one episode at a time ([`second_pass`]). A message is kept only from when it is
//! read until the last episode that takes it is handed over, so memory follows one episode (and
//! the recording's reordering), not the recording.

use crate::ingest::decode::{RosValue, decode};
use crate::ingest::error::IngestError;
use crate::ingest::msgdef::MessageDefs;
use crate::ingest::open::Recording;
use crate::ingest::stamps::{Decoders, TopicSpec};
use crate::ingest::sync::SyncPlan;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::Arc;

/// One frame's messages: per topic (in the order given) the decoded message it takes.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameValues {
    pub time_ns: i64,
    pub values: Vec<Arc<RosValue>>,
}

/// Reads `path` again and calls `episode` with each episode's frames, in order (the plan's
/// episodes, made from the first pass over the same file and `topics`).
pub fn second_pass(
    path: &Path,
    topics: &[TopicSpec],
    plan: &SyncPlan,
    builtin: &MessageDefs,
    episode: &mut dyn FnMut(Vec<FrameValues>) -> Result<(), IngestError>,
) -> Result<(), IngestError> {
    let mut takers = Takers::of(plan);
    let mut decoders = Decoders::new(topics);
    let mut counts = vec![0usize; topics.len()];
    let mut held: BTreeMap<(usize, usize), Arc<RosValue>> = BTreeMap::new();
    let mut next_episode = 0;
    let mut recording = Recording::open(path)?;
    // Not a `for` loop: the recording's channels are looked up while it is read.
    while let Some(message) = recording.next() {
        if next_episode == plan.episodes.len() {
            break;
        }
        let message = message?;
        let Some(decoder) = decoders.get(path, &recording, message.connection, builtin)? else {
            continue;
        };
        let (slot, channel, defs) = (decoder.slot, &decoder.channel, &decoder.defs);
        let index = counts[slot];
        counts[slot] += 1;
        let Some(episodes) = takers.by_message.get(&(slot, index)) else {
            continue;
        };
        let value =
            decode(defs, &channel.type_name, channel.wire, &message.data).map_err(|source| {
                IngestError::Decode {
                    path: path.to_path_buf(),
                    topic: topics[slot].topic.clone(),
                    index,
                    source: Box::new(source),
                }
            })?;
        held.insert((slot, index), Arc::new(value));
        for &e in episodes {
            takers.missing[e] -= 1;
        }
        next_episode = hand_over(plan, &takers, &mut held, next_episode, episode)?;
    }
    Ok(())
}

/// Which episodes take each picked message ((topic slot, message index) -> episodes), and how
/// many picked messages each episode still lacks.
struct Takers {
    by_message: BTreeMap<(usize, usize), BTreeSet<usize>>,
    missing: Vec<usize>,
}

impl Takers {
    fn of(plan: &SyncPlan) -> Takers {
        let mut by_message: BTreeMap<(usize, usize), BTreeSet<usize>> = BTreeMap::new();
        for (e, frames) in plan.episodes.iter().enumerate() {
            for frame in frames {
                for (slot, &pick) in frame.picks.iter().enumerate() {
                    by_message.entry((slot, pick)).or_default().insert(e);
                }
            }
        }
        let mut missing = vec![0; plan.episodes.len()];
        for &e in by_message.values().flatten() {
            missing[e] += 1;
        }
        Takers {
            by_message,
            missing,
        }
    }
}

/// Hands over every episode from `next` on that lacks nothing, letting go of what no later
/// episode takes; returns the next episode to hand over.
fn hand_over(
    plan: &SyncPlan,
    takers: &Takers,
    held: &mut BTreeMap<(usize, usize), Arc<RosValue>>,
    mut next: usize,
    episode: &mut dyn FnMut(Vec<FrameValues>) -> Result<(), IngestError>,
) -> Result<usize, IngestError> {
    while next < plan.episodes.len() && takers.missing[next] == 0 {
        let frames = plan.episodes[next]
            .iter()
            .map(|frame| FrameValues {
                time_ns: frame.time_ns,
                values: (frame.picks.iter().enumerate())
                    .filter_map(|(slot, &pick)| held.get(&(slot, pick)).cloned())
                    .collect(),
            })
            .collect();
        episode(frames)?;
        held.retain(|key, _| {
            (takers.by_message.get(key))
                .and_then(|e| e.last())
                .is_some_and(|&last| last > next)
        });
        next += 1;
    }
    Ok(next)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::builtin::ros2_types;
    use crate::ingest::stamps::{Clock, first_pass};
    use crate::ingest::sync::{StreamKind, SyncOptions, plan};

    /// A ROS 2 MCAP: `/text` (std_msgs/String, receive times as given) and `/tick` at 10 Hz.
    fn recording(texts: &[(u64, &str)], ticks_ms: &[u64]) -> std::path::PathBuf {
        use crate::ingest::fixtures::{cdr_string, mcap_bytes, temp_file};
        let string = "string data\n";
        let channels = [
            ("/text", "std_msgs/msg/String", string),
            ("/tick", "std_msgs/msg/String", string),
        ];
        let mut all: Vec<(u64, usize, String)> = texts
            .iter()
            .map(|(t, s)| (*t, 0, s.to_string()))
            .chain(ticks_ms.iter().map(|t| (t * 1_000_000, 1, format!("t{t}"))))
            .collect();
        all.sort();
        let messages: Vec<(usize, u64, Vec<u8>)> = all
            .into_iter()
            .map(|(time, channel, body)| (channel, time, cdr_string(&body)))
            .collect();
        let name = format!("frames-{}.mcap", ticks_ms.len());
        temp_file(&name, &mcap_bytes(None, &channels, &messages))
    }

    #[test]
    fn each_episode_gets_the_picked_messages_in_order() {
        // Ticks every 100 ms but 300-600 ms: at 10 fps (150 ms tolerance) the 300 ms frame
        // takes the 200 ms tick, 400-600 ms are not written: two episodes.
        let ticks: Vec<u64> = (0..=10)
            .map(|k| k * 100)
            .filter(|t| !(300..=600).contains(t))
            .collect();
        let path = recording(&[(0, "start"), (650_000_000, "later")], &ticks);
        let topics = [
            TopicSpec {
                topic: "/tick".into(),
                kind: StreamKind::Sampled,
                offset_ns: 0,
            },
            TopicSpec {
                topic: "/text".into(),
                kind: StreamKind::Event,
                offset_ns: 0,
            },
        ];
        let builtin = ros2_types().expect("builtin");
        let first = first_pass(&path, &topics, Clock::Receive, &builtin).expect("first");
        let plan = plan(&first.streams, &SyncOptions::at(10)).expect("plan");
        assert_eq!(plan.report.episodes, [4, 4]);
        let mut episodes = Vec::new();
        second_pass(&path, &topics, &plan, &builtin, &mut |frames| {
            let texts: Vec<(String, String)> = frames
                .iter()
                .map(|f| {
                    let text = |v: &RosValue| {
                        v.at("data")
                            .and_then(RosValue::as_str)
                            .unwrap_or("")
                            .to_string()
                    };
                    (text(&f.values[0]), text(&f.values[1]))
                })
                .collect();
            episodes.push(texts);
            Ok(())
        })
        .expect("second");
        let pair = |a: &str, b: &str| (a.to_string(), b.to_string());
        assert_eq!(
            episodes,
            [
                vec![
                    pair("t0", "start"),
                    pair("t100", "start"),
                    pair("t200", "start"),
                    pair("t200", "start")
                ],
                vec![
                    pair("t700", "later"),
                    pair("t800", "later"),
                    pair("t900", "later"),
                    pair("t1000", "later")
                ],
            ]
        );
        std::fs::remove_file(path).ok();
    }
}
