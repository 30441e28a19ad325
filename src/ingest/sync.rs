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
    pub dropped_frames: u64,
    /// Frames written per episode.
    pub episodes: Vec<usize>,
}

/// The frames of each episode, and the report.
#[derive(Clone, Debug, PartialEq)]
pub struct SyncPlan {
    pub episodes: Vec<Vec<Frame>>,
    pub report: SyncReport,
}

/// The most frames one input may make: 10 million, 93 hours at 30 fps (a grid this long comes
/// from stamps on different clocks, or forged ones).
pub const MAX_FRAMES: usize = 10_000_000;

/// Why streams could not be put on frames.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "the streams would make more than {limit} frames at {fps} fps (their stamps span {span_secs} s): are they on one clock? (--clock receive, --time-offset)"
)]
pub struct TooManyFrames {
    pub limit: usize,
    pub fps: u32,
    pub span_secs: i64,
}

/// Puts `streams` on frames by the rule of the module overview. Time goes straight to the next
/// frame that can be written (a stream's next message), so a long gap costs nothing; more than
/// [`MAX_FRAMES`] written frames is an error.
pub fn plan(streams: &[StreamStamps], options: &SyncOptions) -> Result<SyncPlan, TooManyFrames> {
    let sorted: Vec<Vec<usize>> = streams.iter().map(|s| by_stamp(&s.stamps_ns)).collect();
    let fps = options.fps.max(1);
    let grid = grid_span(streams).map(|(start, end)| Grid::new(start, end, fps));
    let mut episodes: Vec<Vec<Frame>> = Vec::new();
    let mut current: Vec<Frame> = Vec::new();
    let (mut dropped, mut written) = (0u64, 0usize);
    if let Some(grid) = &grid {
        let mut cursors = vec![0usize; streams.len()];
        let mut k = 0;
        while k <= grid.last {
            let time_ns = grid.time(k);
            match frame_at(
                streams,
                &sorted,
                &mut cursors,
                time_ns,
                options.tolerance_ns,
            ) {
                Ok(picks) => {
                    written += 1;
                    if written > MAX_FRAMES {
                        return Err(TooManyFrames {
                            limit: MAX_FRAMES,
                            fps,
                            span_secs: (grid.end - grid.start) / 1_000_000_000,
                        });
                    }
                    current.push(Frame { time_ns, picks });
                    k += 1;
                }
                Err(next_ns) => {
                    let next = next_ns.map_or(grid.last + 1, |t| grid.first_at_or_after(t));
                    let next = next.clamp(k + 1, grid.last + 1);
                    dropped += next - k;
                    k = next;
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
        grid: grid.map(|g| (g.start, g.time(g.last))),
        streams: streams
            .iter()
            .map(|s| stream_report(s, options.tolerance_ns))
            .collect(),
        dropped_frames: dropped,
        episodes: episodes.iter().map(Vec::len).collect(),
    };
    Ok(SyncPlan { episodes, report })
}

/// The frame grid: frame k at `start + floor(k * 1e9 / fps)` ns, k from 0 to `last`.
struct Grid {
    start: i64,
    end: i64,
    fps: i128,
    last: u64,
}

impl Grid {
    fn new(start: i64, end: i64, fps: u32) -> Grid {
        let fps = i128::from(fps);
        // The largest k with floor(k * 1e9 / fps) <= end - start.
        let span = i128::from(end) - i128::from(start);
        let last = ceil_div((span + 1) * fps, 1_000_000_000) - 1;
        Grid {
            start,
            end,
            fps,
            last: u64::try_from(last).unwrap_or(0),
        }
    }

    fn time(&self, k: u64) -> i64 {
        let offset = i128::from(k) * 1_000_000_000 / self.fps;
        i64::try_from(i128::from(self.start) + offset).unwrap_or(i64::MAX)
    }

    /// The first k whose time is at or after `time_ns`.
    fn first_at_or_after(&self, time_ns: i64) -> u64 {
        let span = i128::from(time_ns) - i128::from(self.start);
        u64::try_from(ceil_div(span * self.fps, 1_000_000_000)).unwrap_or(0)
    }
}

/// `a / b` rounded up, for `b` > 0.
fn ceil_div(a: i128, b: i128) -> i128 {
    a / b + i128::from(a % b > 0)
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

/// Each stream's pick at `time_ns` (cursors advance with time); when the frame is not written,
/// the earliest time one could be (None: never again).
fn frame_at(
    streams: &[StreamStamps],
    sorted: &[Vec<usize>],
    cursors: &mut [usize],
    time_ns: i64,
    tolerance_ns: i64,
) -> Result<Vec<usize>, Option<i64>> {
    let mut picks = Vec::with_capacity(streams.len());
    // Not written: the time the slowest stream is fit again (None: never).
    let mut next: Option<Option<i64>> = None;
    for ((stream, order), cursor) in streams.iter().zip(sorted).zip(cursors.iter_mut()) {
        while *cursor < order.len() && stream.stamps_ns[order[*cursor]] <= time_ns {
            *cursor += 1;
        }
        let pick = cursor.checked_sub(1).and_then(|c| order.get(c));
        let fit = pick.is_some_and(|&pick| {
            stream.kind == StreamKind::Event || time_ns - stream.stamps_ns[pick] <= tolerance_ns
        });
        if fit {
            picks.extend(pick);
            continue;
        }
        let again = order.get(*cursor).map(|&i| stream.stamps_ns[i]);
        next = Some(match (next, again) {
            (Some(None), _) | (_, None) => None,
            (Some(Some(a)), Some(b)) => Some(a.max(b)),
            (None, Some(b)) => Some(b),
        });
    }
    match next {
        None => Ok(picks),
        Some(again) => Err(again),
    }
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
        let plan = plan(&streams(), &SyncOptions::at(10)).expect("plan");
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
        let split = plan(&streams, &SyncOptions::at(10)).expect("plan");
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
        )
        .expect("plan");
        assert_eq!(dropped.report.episodes, [9]);
        let strict = plan(
            &streams,
            &SyncOptions {
                tolerance_ns: 50 * MS,
                ..SyncOptions::at(10)
            },
        )
        .expect("plan");
        assert_eq!(strict.report.dropped_frames, 2, "305 and 405 ms");
    }

    #[test]
    fn ties_take_the_later_message_and_out_of_order_stamps_are_counted() {
        let streams = vec![
            stream("/camera", StreamKind::Sampled, &[0, 100, 100, 50, 200]),
            stream("/state", StreamKind::Sampled, &[0, 200]),
        ];
        let plan = plan(&streams, &SyncOptions::at(10)).expect("plan");
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
        let plan = plan(&streams, &SyncOptions::at(10)).expect("plan");
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
        let plan = plan(&streams, &SyncOptions::at(10)).expect("plan");
        assert!(plan.episodes.is_empty() && plan.report.grid.is_none());
        let empty = vec![stream("/a", StreamKind::Sampled, &[])];
        assert!(
            super::plan(&empty, &SyncOptions::at(10))
                .expect("plan")
                .episodes
                .is_empty()
        );
    }

    #[test]
    fn a_gap_of_centuries_is_stepped_over_and_a_grid_too_long_is_refused() {
        const YEAR_2262: i64 = 9_000_000_000_000_000_000;
        let streams = vec![
            stream("/camera", StreamKind::Sampled, &[0, 100]),
            stream("/state", StreamKind::Sampled, &[0, 100]),
        ];
        let mut far = streams.clone();
        for s in &mut far {
            s.stamps_ns.push(YEAR_2262);
        }
        // 2.7e11 grid times: a frame-by-frame walk would not return (no timed assertion; the
        // counts below are what the step over the gap must get right).
        let plan = plan(&far, &SyncOptions::at(30)).expect("plan");
        // 0, 33, 100 and 133 ms (66 ms is 66 ms old), then the frame at the far stamps.
        assert_eq!(plan.report.episodes, [2, 2, 1]);
        let grid = Grid::new(0, YEAR_2262, 30);
        assert_eq!(plan.report.grid, Some((0, grid.time(grid.last))));
        assert_eq!(plan.report.dropped_frames, grid.last + 1 - 5);
        // Messages every 10 ms over 100 hours at 30 fps: too many frames.
        let dense: Vec<i64> = (0..=36_000_000).map(|k| k * 10).collect();
        let long = vec![stream("/camera", StreamKind::Sampled, &dense)];
        let error = super::plan(&long, &SyncOptions::at(30)).expect_err("too long");
        assert_eq!(error.limit, MAX_FRAMES);
        assert!(error.to_string().contains("--clock receive"), "{error}");
        // Within the limit, the same rule as before.
        assert_eq!(
            super::plan(&streams, &SyncOptions::at(10))
                .expect("plan")
                .report
                .episodes,
            [2]
        );
    }
}
