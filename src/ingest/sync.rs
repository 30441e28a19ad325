//! Synchronisation of a recording's streams onto frames, stated and reported: the rule
//! `surgvla ingest` applies, on stamps only (the messages themselves are read in a second pass,
//! so a bag is never held whole).
//!
//! The rule:
//! - frames lie on a uniform grid at `fps`, from the latest first message to the earliest last
//!   message over the *sampled* streams (measured state, cameras), frame k at
//!   `start + floor(k * 1e9 / fps)` ns;
//! - each frame takes, per stream, the message with the greatest stamp at or before it (equal
//!   stamps: the later one in the recording);
//! - a frame where a sampled stream's message is older than the tolerance is not written;
//!   *event* streams (commands: an idle arm publishes none) hold their last value however old,
//!   and a frame before an event stream's first message is not written either;
//! - where frames are not written, [`OnGap::Split`] starts a new episode after the gap (every
//!   episode continuous at `fps`), [`OnGap::Drop`] keeps one episode and numbers the frames on.
//!
//! Nothing is interpolated. The [`SyncReport`] says, per stream, its count, rate, jitter, gaps
//! longer than the tolerance and stamps that went backwards, and overall the frames not written
//! and the episodes made.

use serde::Serialize;

/// A stream's role in synchronisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StreamKind {
    /// Measured state and cameras: too old a message means the frame is not written.
    Sampled,
    /// Commands and the instruction: the last value holds however old.
    Event,
}

/// One stream's stamps, in recording order.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamStamps {
    pub topic: String,
    pub kind: StreamKind,
    /// Each message's time (its header stamp, or receive time, offset as asked), ns.
    pub stamps_ns: Vec<i64>,
}

/// What happens where frames are not written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OnGap {
    /// A new episode after each gap: every episode continuous at the frame rate.
    #[default]
    Split,
    /// One episode; the written frames numbered on (timestamps k / fps).
    Drop,
}

/// How streams are put on frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyncOptions {
    pub fps: u32,
    /// A sampled stream's message older than this misses the frame.
    pub tolerance_ns: i64,
    pub on_gap: OnGap,
}

impl SyncOptions {
    /// `fps` with the default tolerance, 1.5 frame periods.
    pub fn at(fps: u32) -> SyncOptions {
        SyncOptions {
            fps,
            tolerance_ns: 1_500_000_000 / i64::from(fps.max(1)),
            on_gap: OnGap::Split,
        }
    }
}

/// One written frame: its grid time and, per stream (in the order given), the index of the
/// message it takes (in recording order).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub time_ns: i64,
    pub picks: Vec<usize>,
}

/// A gap in a stream: consecutive stamps further apart than the tolerance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Gap {
    pub start: i64,
    pub end: i64,
}

/// What one stream looked like.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StreamReport {
    pub topic: String,
    pub kind: StreamKind,
    pub count: usize,
    /// Messages per second over its span (0 for fewer than two).
    pub rate_hz: f64,
    /// Standard deviation of the intervals between consecutive stamps, ms.
    pub jitter_ms: f64,
    /// Sampled streams: intervals longer than the tolerance.
    pub gaps: Vec<Gap>,
    /// Messages stamped earlier than the message before them in the recording.
    pub out_of_order: usize,
}

/// The synchronisation of one input, as its report says it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SyncReport {
    pub fps: u32,
    pub tolerance_ms: f64,
    pub on_gap: OnGap,
    /// The grid's first and last frame times (ns); None when the sampled streams never
    /// overlap.
    pub grid: Option<(i64, i64)>,
    pub streams: Vec<StreamReport>,
    /// Grid times not written (a sampled stream too old, or an event stream not started).
    pub dropped_frames: usize,
    /// Frames written per episode.
    pub episodes: Vec<usize>,
}

/// The frames of each episode, and the report.
#[derive(Clone, Debug, PartialEq)]
pub struct SyncPlan {
    pub episodes: Vec<Vec<Frame>>,
    pub report: SyncReport,
}

/// Puts `streams` on frames by the rule of the module overview.
pub fn plan(streams: &[StreamStamps], options: &SyncOptions) -> SyncPlan {
    let sorted: Vec<Vec<usize>> = streams.iter().map(|s| by_stamp(&s.stamps_ns)).collect();
    let grid = grid_span(streams);
    let mut episodes: Vec<Vec<Frame>> = Vec::new();
    let mut current: Vec<Frame> = Vec::new();
    let mut dropped = 0;
    if let Some((start, end)) = grid {
        let mut cursors = vec![0usize; streams.len()];
        let fps = i64::from(options.fps.max(1));
        for k in 0i64.. {
            let Some(time_ns) = k
                .checked_mul(1_000_000_000)
                .map(|t| t / fps)
                .and_then(|t| start.checked_add(t))
                .filter(|t| *t <= end)
            else {
                break;
            };
            match frame_at(
                streams,
                &sorted,
                &mut cursors,
                time_ns,
                options.tolerance_ns,
            ) {
                Some(picks) => current.push(Frame { time_ns, picks }),
                None => {
                    dropped += 1;
                    if options.on_gap == OnGap::Split && !current.is_empty() {
                        episodes.push(std::mem::take(&mut current));
                    }
                }
            }
        }
    }
    if !current.is_empty() {
        episodes.push(current);
    }
    let report = SyncReport {
        fps: options.fps,
        tolerance_ms: options.tolerance_ns as f64 / 1e6,
        on_gap: options.on_gap,
        grid: grid.and_then(|(start, end)| {
            let fps = i64::from(options.fps.max(1));
            let last = (end - start).checked_mul(fps)? / 1_000_000_000;
            Some((start, start + last * 1_000_000_000 / fps))
        }),
        streams: streams
            .iter()
            .map(|s| stream_report(s, options.tolerance_ns))
            .collect(),
        dropped_frames: dropped,
        episodes: episodes.iter().map(Vec::len).collect(),
    };
    SyncPlan { episodes, report }
}

/// Message indices in (stamp, recording order) order.
fn by_stamp(stamps: &[i64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..stamps.len()).collect();
    order.sort_by_key(|&i| (stamps[i], i));
    order
}

/// From the latest first stamp to the earliest last stamp over the sampled streams.
fn grid_span(streams: &[StreamStamps]) -> Option<(i64, i64)> {
    let sampled = streams.iter().filter(|s| s.kind == StreamKind::Sampled);
    let mut span: Option<(i64, i64)> = None;
    for stream in sampled {
        let first = *stream.stamps_ns.iter().min()?;
        let last = *stream.stamps_ns.iter().max()?;
        span = Some(match span {
            None => (first, last),
            Some((start, end)) => (start.max(first), end.min(last)),
        });
    }
    span.filter(|(start, end)| start <= end)
}

/// Each stream's pick at `time_ns` (cursors advance with time), or None when the frame is not
/// written.
fn frame_at(
    streams: &[StreamStamps],
    sorted: &[Vec<usize>],
    cursors: &mut [usize],
    time_ns: i64,
    tolerance_ns: i64,
) -> Option<Vec<usize>> {
    let mut picks = Vec::with_capacity(streams.len());
    let mut written = true;
    for ((stream, order), cursor) in streams.iter().zip(sorted).zip(cursors.iter_mut()) {
        while *cursor < order.len() && stream.stamps_ns[order[*cursor]] <= time_ns {
            *cursor += 1;
        }
        let Some(&pick) = cursor.checked_sub(1).and_then(|c| order.get(c)) else {
            written = false;
            continue;
        };
        if stream.kind == StreamKind::Sampled && time_ns - stream.stamps_ns[pick] > tolerance_ns {
            written = false;
        }
        picks.push(pick);
    }
    written.then_some(picks)
}

fn stream_report(stream: &StreamStamps, tolerance_ns: i64) -> StreamReport {
    let stamps = &stream.stamps_ns;
    let out_of_order = stamps.windows(2).filter(|w| w[1] < w[0]).count();
    let mut sorted = stamps.clone();
    sorted.sort_unstable();
    let intervals: Vec<i64> = sorted.windows(2).map(|w| w[1] - w[0]).collect();
    let (rate_hz, jitter_ms) = match (sorted.first(), sorted.last()) {
        (Some(first), Some(last)) if last > first => {
            let rate = (sorted.len() - 1) as f64 / ((last - first) as f64 / 1e9);
            let mean = intervals.iter().sum::<i64>() as f64 / intervals.len() as f64;
            let variance = intervals
                .iter()
                .map(|&i| (i as f64 - mean).powi(2))
                .sum::<f64>()
                / intervals.len() as f64;
            (rate, variance.sqrt() / 1e6)
        }
        _ => (0.0, 0.0),
    };
    let gaps = match stream.kind {
        StreamKind::Sampled => sorted
            .windows(2)
            .filter(|w| w[1] - w[0] > tolerance_ns)
            .map(|w| Gap {
                start: w[0],
                end: w[1],
            })
            .collect(),
        StreamKind::Event => Vec::new(),
    };
    StreamReport {
        topic: stream.topic.clone(),
        kind: stream.kind,
        count: stamps.len(),
        rate_hz,
        jitter_ms,
        gaps,
        out_of_order,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    fn stream(topic: &str, kind: StreamKind, stamps_ms: &[i64]) -> StreamStamps {
        StreamStamps {
            topic: topic.into(),
            kind,
            stamps_ns: stamps_ms.iter().map(|t| t * MS).collect(),
        }
    }

    /// A camera at 10 Hz from 0 ms and a state stream at 100 Hz from 5 ms, both to 1 s.
    fn streams() -> Vec<StreamStamps> {
        let camera: Vec<i64> = (0..=10).map(|k| k * 100).collect();
        let state: Vec<i64> = (0..100).map(|k| 5 + k * 10).collect();
        vec![
            stream("/camera", StreamKind::Sampled, &camera),
            stream("/state", StreamKind::Sampled, &state),
        ]
    }

    #[test]
    fn the_grid_spans_the_overlap_and_each_frame_takes_the_latest_message_at_or_before_it() {
        let plan = plan(&streams(), &SyncOptions::at(10));
        assert_eq!(plan.report.grid, Some((5 * MS, 905 * MS)));
        assert_eq!(plan.episodes.len(), 1);
        let frames = &plan.episodes[0];
        assert_eq!(frames.len(), 10);
        // Frame 1 at 105 ms: camera 100 ms (index 1), state 105 ms (index 10).
        assert_eq!(frames[1].time_ns, 105 * MS);
        assert_eq!(frames[1].picks, [1, 10]);
        assert_eq!(plan.report.dropped_frames, 0);
        let camera = &plan.report.streams[0];
        assert_eq!(camera.count, 11);
        assert!((camera.rate_hz - 10.0).abs() < 1e-9);
        assert!(camera.jitter_ms.abs() < 1e-9 && camera.gaps.is_empty());
    }

    #[test]
    fn a_dropout_is_reported_and_splits_or_is_dropped() {
        let mut streams = streams();
        // The camera misses 300 and 400 ms.
        streams[0]
            .stamps_ns
            .retain(|t| *t != 300 * MS && *t != 400 * MS);
        let split = plan(&streams, &SyncOptions::at(10));
        let gaps = &split.report.streams[0].gaps;
        assert_eq!(
            gaps,
            &[Gap {
                start: 200 * MS,
                end: 500 * MS
            }]
        );
        // 305 ms takes the 200 ms frame: 105 ms old, within 150 ms; 405 ms is 205 ms old.
        assert_eq!(split.report.dropped_frames, 1);
        assert_eq!(split.report.episodes, [4, 5]);
        assert_eq!(split.episodes[1][0].time_ns, 505 * MS);
        let dropped = plan(
            &streams,
            &SyncOptions {
                on_gap: OnGap::Drop,
                ..SyncOptions::at(10)
            },
        );
        assert_eq!(dropped.report.episodes, [9]);
        let strict = plan(
            &streams,
            &SyncOptions {
                tolerance_ns: 50 * MS,
                ..SyncOptions::at(10)
            },
        );
        assert_eq!(strict.report.dropped_frames, 2, "305 and 405 ms");
    }

    #[test]
    fn ties_take_the_later_message_and_out_of_order_stamps_are_counted() {
        let streams = vec![
            stream("/camera", StreamKind::Sampled, &[0, 100, 100, 50, 200]),
            stream("/state", StreamKind::Sampled, &[0, 200]),
        ];
        let plan = plan(&streams, &SyncOptions::at(10));
        let frames = &plan.episodes[0];
        assert_eq!(frames[1].time_ns, 100 * MS);
        assert_eq!(
            frames[1].picks[0], 2,
            "the later of the two 100 ms messages"
        );
        assert_eq!(plan.report.streams[0].out_of_order, 1);
    }

    #[test]
    fn events_hold_however_old_but_not_before_they_start() {
        let mut streams = streams();
        streams.push(stream("/setpoint", StreamKind::Event, &[250]));
        let plan = plan(&streams, &SyncOptions::at(10));
        // 5, 105 and 205 ms come before the first command.
        assert_eq!(plan.report.dropped_frames, 3);
        assert_eq!(plan.report.episodes, [7]);
        assert!(plan.episodes[0].iter().all(|f| f.picks[2] == 0));
        assert!(plan.report.streams[2].gaps.is_empty());
    }

    #[test]
    fn streams_that_never_overlap_make_no_frame() {
        let streams = vec![
            stream("/a", StreamKind::Sampled, &[0, 100]),
            stream("/b", StreamKind::Sampled, &[200, 300]),
        ];
        let plan = plan(&streams, &SyncOptions::at(10));
        assert!(plan.episodes.is_empty() && plan.report.grid.is_none());
        let empty = vec![stream("/a", StreamKind::Sampled, &[])];
        assert!(
            super::plan(&empty, &SyncOptions::at(10))
                .episodes
                .is_empty()
        );
    }
}
