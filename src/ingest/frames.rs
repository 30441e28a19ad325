//! The second pass over a recording: the messages the synchronisation plan picked, decoded,
//! handed over frame by frame ([`second_pass`]), each frame as soon as every message it takes
//! has been read, with a mark at each episode's end. A message is kept only from when it is
//! read until the last frame that takes it is handed over, so memory follows the recording's
//! reordering (how far a message's place in the file is from its stamp's), not the recording.

use crate::ingest::decode::{RosValue, decode};
use crate::ingest::error::IngestError;
use crate::ingest::msgdef::MessageDefs;
use crate::ingest::open::{BagInput, Recording};
use crate::ingest::stamps::{Decoders, TopicSpec};
use crate::ingest::sync::SyncPlan;
use std::collections::HashMap;
use std::sync::Arc;

/// One frame's messages: per topic (in the order given) the decoded message it takes.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameValues {
    pub time_ns: i64,
    pub values: Vec<Arc<RosValue>>,
}

/// What the second pass hands over, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Handed {
    /// The next frame of the current episode.
    Frame(FrameValues),
    /// The current episode has no more frames.
    EpisodeEnd,
}

/// Reads `path` again and hands over each frame of the plan's episodes, in order, then each
/// episode's end (the plan made from the first pass over the same file and `topics`).
pub fn second_pass(
    input: BagInput<'_>,
    topics: &[TopicSpec],
    plan: &SyncPlan,
    builtin: &MessageDefs,
    hand: &mut dyn FnMut(Handed) -> Result<(), IngestError>,
) -> Result<(), IngestError> {
    let mut takers = Takers::of(plan);
    let mut decoders = Decoders::new(topics);
    let mut counts = vec![0usize; topics.len()];
    let mut held: HashMap<(usize, usize), Arc<RosValue>> = HashMap::new();
    let mut handing = Handing::default();
    let mut recording = Recording::open(input)?;
    let path = input.path;
    // Not a `for` loop: the recording's channels are looked up while it is read.
    while let Some(message) = recording.next() {
        if handing.frame == takers.frames.len() {
            break;
        }
        let message = message?;
        let Some(decoder) = decoders.get(path, &recording, message.connection, builtin)? else {
            continue;
        };
        let (slot, channel, defs) = (decoder.slot, &decoder.channel, &decoder.defs);
        let index = counts[slot];
        counts[slot] += 1;
        let Some(&(first, last)) = takers.by_message.get(&(slot, index)) else {
            continue;
        };
        let value = decode(defs, &channel.type_name, channel.wire, &message.data)
            .map_err(|source| IngestError::decode(path, &topics[slot].topic, index, source))?;
        held.insert((slot, index), Arc::new(value));
        for missing in &mut takers.missing[first..=last] {
            *missing -= 1;
        }
        handing.hand_over(plan, &takers, &mut held, hand)?;
    }
    Ok(())
}

/// Every written frame in order, as (episode, frame in episode); which frames take each picked
/// message ((topic slot, message index) -> the first and last frame: a stream's picks only move
/// forward, so they are a run); how many picked messages each frame still lacks.
struct Takers {
    frames: Vec<(usize, usize)>,
    by_message: HashMap<(usize, usize), (usize, usize)>,
    missing: Vec<usize>,
}

impl Takers {
    fn of(plan: &SyncPlan) -> Takers {
        let mut frames = Vec::new();
        let mut by_message: HashMap<(usize, usize), (usize, usize)> = HashMap::new();
        let mut missing = Vec::new();
        for (e, episode) in plan.episodes.iter().enumerate() {
            for (f, frame) in episode.iter().enumerate() {
                let global = frames.len();
                frames.push((e, f));
                missing.push(0);
                for (slot, &pick) in frame.picks.iter().enumerate() {
                    by_message.entry((slot, pick)).or_insert((global, global)).1 = global;
                }
            }
        }
        // Each frame lacks one message per stream (its runs cover it).
        for &(first, last) in by_message.values() {
            for missing in &mut missing[first..=last] {
                *missing += 1;
            }
        }
        Takers {
            frames,
            by_message,
            missing,
        }
    }
}

/// Where the hand-over is: the next frame (a global number) to hand over.
#[derive(Default)]
struct Handing {
    frame: usize,
}

impl Handing {
    /// Hands over every frame from the next on that lacks nothing (and each episode's end),
    /// letting go of what no later frame takes.
    fn hand_over(
        &mut self,
        plan: &SyncPlan,
        takers: &Takers,
        held: &mut HashMap<(usize, usize), Arc<RosValue>>,
        hand: &mut dyn FnMut(Handed) -> Result<(), IngestError>,
    ) -> Result<(), IngestError> {
        while self.frame < takers.frames.len() && takers.missing[self.frame] == 0 {
            let (e, f) = takers.frames[self.frame];
            let frame = &plan.episodes[e][f];
            let values = (frame.picks.iter().enumerate())
                .filter_map(|(slot, &pick)| held.get(&(slot, pick)).cloned())
                .collect();
            hand(Handed::Frame(FrameValues {
                time_ns: frame.time_ns,
                values,
            }))?;
            for (slot, &pick) in frame.picks.iter().enumerate() {
                if takers.by_message.get(&(slot, pick)).map(|r| r.1) == Some(self.frame) {
                    held.remove(&(slot, pick));
                }
            }
            if f + 1 == plan.episodes[e].len() {
                hand(Handed::EpisodeEnd)?;
            }
            self.frame += 1;
        }
        Ok(())
    }
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
        let mut episodes = vec![Vec::new()];
        second_pass(
            BagInput::new(&path, None),
            &topics,
            &plan,
            &builtin,
            &mut |handed| {
                match handed {
                    Handed::Frame(f) => {
                        let text = |v: &RosValue| {
                            v.at("data")
                                .and_then(RosValue::as_str)
                                .unwrap_or("")
                                .to_string()
                        };
                        let current = episodes.last_mut().expect("an episode");
                        current.push((text(&f.values[0]), text(&f.values[1])));
                    }
                    Handed::EpisodeEnd => episodes.push(Vec::new()),
                }
                Ok(())
            },
        )
        .expect("second");
        assert_eq!(episodes.pop(), Some(Vec::new()), "the last episode ended");
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
