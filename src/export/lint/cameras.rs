//! Cameras, judged from a summary of every decoded frame ([`FrameLook`]: its grey level's mean
//! and spread, a hash of its pixels and an 8 x 8 thumbnail): blank frames (black, or one
//! colour), a camera frozen while the robot moves (the same picture frame after frame), and two
//! cameras of one shape swapped within an episode. Only where frames are decoded (the full
//! pass): lerobot-doctor decodes none. Video frames are all looked at; PNG frames as
//! [`LOOK_EVERY`] says. Segmentation masks (`*mask*`, `*segment*`) are
//! mostly background by nature and are not judged.

use super::series::{EpisodeSeries, Lint, LintDataset};
use crate::export::check::Check;
use std::collections::BTreeMap;

/// A frame whose grey levels spread less than this (standard deviation, 0..255) is blank.
pub const BLANK_STD: f32 = 2.0;
/// A camera showing the same picture for this many consecutive frames (and half a second)
/// while the robot's state changes is frozen.
pub const FROZEN_FRAMES: usize = 3;
/// Cameras are swapped at a frame when each looks more like the other's previous frame than
/// its own, by this factor.
pub const SWAP_FACTOR: f64 = 0.5;
/// Pixels sampled for the spread and thumbnail: every this many, across and down.
const SAMPLE_STEP: usize = 2;
/// PNG frames are all hashed (from their filtered rows), and their pixels looked at where a
/// check needs them: every frame that could be blank ([`could_be_blank`]), every frame that
/// repeats the one before it, and, where a camera has another of its shape it could be swapped
/// with, every this many frames. Unfiltering the rest would be most of the full pass's cost.
pub const LOOK_EVERY: u64 = 4;
/// The thumbnail's side, in blocks.
const THUMB_SIDE: usize = 8;

/// What the lint keeps of one decoded frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameLook {
    pub frame: u64,
    /// Whether the pixels were looked at: the grey levels and thumbnail are known.
    pub seen: bool,
    /// Grey level (0..255): mean and standard deviation.
    pub mean: f32,
    pub std: f32,
    /// A hash of the pixels (of a PNG's filtered rows): equal pictures, equal hashes.
    pub hash: u64,
    /// Mean grey level of each of 8 x 8 blocks.
    pub thumb: [u8; THUMB_SIDE * THUMB_SIDE],
}

impl FrameLook {
    /// The look of a frame of `width` x `height` pixels of `channels` interleaved 8-bit
    /// channels (grey is their mean).
    pub fn of(frame: u64, width: usize, height: usize, channels: usize, pixels: &[u8]) -> Self {
        Self::of_hashed(frame, (width, height, channels), pixels, hash(pixels))
    }

    /// A frame known by its hash only (its pixels not looked at).
    pub fn unseen(frame: u64, hash: u64) -> Self {
        FrameLook {
            frame,
            seen: false,
            mean: 0.0,
            std: 0.0,
            hash,
            thumb: [0; THUMB_SIDE * THUMB_SIDE],
        }
    }

    /// [`FrameLook::of`] with the hash already taken (of a PNG's filtered rows).
    pub fn of_hashed(
        frame: u64,
        (width, height, channels): (usize, usize, usize),
        pixels: &[u8],
        hash: u64,
    ) -> Self {
        let channels = channels.max(1);
        let (width, height) = (width.max(1), height.max(1));
        // Integer sums of the channels' sum per pixel (grey times `channels`): no division per
        // pixel, and each column's block looked up, not computed.
        let (mut sum, mut sum_sq, mut n) = (0u64, 0u64, 0u64);
        let mut blocks = [(0u64, 0u64); THUMB_SIDE * THUMB_SIDE];
        // Each block's columns, starting on an even (sampled) column.
        let edge = |b: usize| {
            (b * width / THUMB_SIDE)
                .next_multiple_of(SAMPLE_STEP)
                .min(width)
        };
        let column_spans: Vec<std::ops::Range<usize>> =
            (0..THUMB_SIDE).map(|b| edge(b)..edge(b + 1)).collect();
        // Every other pixel of every other row: the spread and the thumbnail need no more (the
        // hash reads every byte).
        let stride = width * channels;
        for y in (0..height.min(pixels.len() / stride.max(1))).step_by(SAMPLE_STEP) {
            let row = &pixels[y * stride..(y + 1) * stride];
            let row_block = (y * THUMB_SIDE / height).min(THUMB_SIDE - 1) * THUMB_SIDE;
            let (mut row_sum, mut row_sq) = (0u64, 0u64);
            // Each thumbnail block's stretch of the row, summed apart.
            for (b, span) in column_spans.iter().enumerate() {
                let mut block_sum = 0u64;
                for x in span.clone().step_by(SAMPLE_STEP) {
                    let at = x * channels;
                    let level: u64 = match channels {
                        1 => u64::from(row[at]),
                        3 => u64::from(row[at]) + u64::from(row[at + 1]) + u64::from(row[at + 2]),
                        _ => row[at..at + channels].iter().map(|v| u64::from(*v)).sum(),
                    };
                    block_sum += level;
                    row_sq += level * level;
                }
                row_sum += block_sum;
                let cell = &mut blocks[row_block + b];
                cell.0 += block_sum;
                cell.1 += span.clone().step_by(SAMPLE_STEP).len() as u64;
            }
            sum += row_sum;
            sum_sq += row_sq;
            n += width.div_ceil(SAMPLE_STEP) as u64;
        }
        let c = channels as f64;
        let (mean, std) = if n > 0 {
            let mean = sum as f64 / n as f64 / c;
            let var = sum_sq as f64 / n as f64 / (c * c) - mean * mean;
            (mean, var.max(0.0).sqrt())
        } else {
            (0.0, 0.0)
        };
        FrameLook {
            frame,
            seen: true,
            mean: mean as f32,
            std: std as f32,
            hash,
            thumb: blocks.map(|(s, count)| {
                (s.checked_div(count * channels as u64).unwrap_or(0)).min(255) as u8
            }),
        }
    }

    fn distance(&self, other: &FrameLook) -> f64 {
        (self.thumb.iter().zip(&other.thumb))
            .map(|(a, b)| f64::from(a.abs_diff(*b)))
            .sum()
    }
}

/// Whether a feature is a segmentation mask: mostly background by nature, not a camera to
/// judge.
pub fn is_mask(feature: &str) -> bool {
    feature.contains("mask") || feature.contains("segment")
}

/// Whether a PNG frame could be blank, from its filtered `rows` (each a filter type and
/// `stride` bytes of `pixel_bytes`-byte pixels): in a picture whose grey levels spread less than
/// [`BLANK_STD`], what the filters leave (each byte's difference to a prediction from its
/// neighbours; in an unfiltered row, to the pixel on its left) is small everywhere, bar a few.
/// Rendered surgical scenes leave 0.5-1.6 % of bytes above [`LARGE_RESIDUAL`]; a candidate
/// leaves under 0.1 %. Every blank frame is a candidate, so candidates are all looked at.
pub fn could_be_blank(rows: &[u8], stride: usize, pixel_bytes: usize) -> bool {
    let mut large = 0;
    for row in rows.chunks_exact(stride + 1) {
        let bytes = &row[1..];
        large += if row[0] == 0 {
            // Unfiltered (rare): each byte against the same channel of the pixel on its left.
            let left = bytes
                .iter()
                .zip(bytes.get(pixel_bytes..).unwrap_or_default());
            left.filter(|(a, b)| is_large(b.wrapping_sub(**a))).count()
        } else {
            count_large(bytes)
        };
    }
    large * 1000 < rows.len()
}

/// |b as i8| > LARGE_RESIDUAL, as one unsigned comparison.
fn is_large(b: u8) -> bool {
    b.wrapping_sub(LARGE_RESIDUAL + 1) < u8::MAX - 2 * LARGE_RESIDUAL
}

/// How many bytes are [`is_large`], counted in byte lanes the processor adds side by side
/// (blocks of 255 cannot overflow them).
fn count_large(bytes: &[u8]) -> usize {
    bytes
        .chunks(255)
        .map(|block| usize::from(block.iter().fold(0u8, |n, b| n + u8::from(is_large(*b)))))
        .sum()
}

/// A filtered byte further than this from its prediction marks an edge or texture.
const LARGE_RESIDUAL: u8 = 24;

/// A hash of the bytes, eight at a time (equal pictures, equal hashes).
pub fn hash(bytes: &[u8]) -> u64 {
    const K: u64 = 0x9e37_79b9_7f4a_7c15;
    // Four lanes of eight bytes, for the processor to run side by side.
    let mut lanes = [bytes.len() as u64, 1, 2, 3];
    let mut blocks = bytes.chunks_exact(32);
    for block in &mut blocks {
        for (lane, word) in lanes.iter_mut().zip(block.chunks_exact(8)) {
            let mut w = [0u8; 8];
            w.copy_from_slice(word);
            *lane = (lane.rotate_left(5) ^ u64::from_le_bytes(w)).wrapping_mul(K);
        }
    }
    let mut h = lanes
        .iter()
        .fold(0u64, |h, lane| (h.rotate_left(7) ^ lane).wrapping_mul(K));
    for byte in blocks.remainder() {
        h = (h.rotate_left(5) ^ u64::from(*byte)).wrapping_mul(K);
    }
    h
}

/// One camera's frames of one episode, in frame order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraFrames {
    pub episode: u64,
    pub camera: String,
    /// (width, height, channels), to pair cameras that could be swapped.
    pub shape: (usize, usize, usize),
    pub frames: Vec<FrameLook>,
}

pub(super) fn check(
    lint: &mut Lint<'_>,
    dataset: &LintDataset,
    episodes: &[EpisodeSeries],
    cameras: &[CameraFrames],
) {
    let cameras: Vec<&CameraFrames> = cameras.iter().filter(|c| !is_mask(&c.camera)).collect();
    for camera in &cameras {
        blank(lint, camera);
    }
    lint.done(Check::BlankCamera, true, "no camera frame is blank");
    let states: BTreeMap<u64, &EpisodeSeries> = episodes.iter().map(|e| (e.episode, e)).collect();
    let run = FROZEN_FRAMES.max(dataset.fps.map_or(0, |f| (f / 2.0).ceil() as usize));
    for camera in &cameras {
        frozen(lint, camera, states.get(&camera.episode).copied(), run);
    }
    lint.done(
        Check::FrozenCamera,
        true,
        "no camera shows one picture while the robot moves",
    );
    let mut by_episode: BTreeMap<u64, Vec<&CameraFrames>> = BTreeMap::new();
    for camera in cameras {
        by_episode.entry(camera.episode).or_default().push(camera);
    }
    for group in by_episode.values() {
        for (i, a) in group.iter().enumerate() {
            for b in group.iter().skip(i + 1).filter(|b| b.shape == a.shape) {
                swapped(lint, a, b);
            }
        }
    }
    lint.done(
        Check::CameraSwap,
        false,
        "no two cameras trade pictures within an episode",
    );
}

fn blank(lint: &mut Lint<'_>, camera: &CameraFrames) {
    // Every frame that could be blank is looked at: the count is of all frames.
    let blank: Vec<&FrameLook> = (camera.frames.iter())
        .filter(|f| f.seen && f.std < BLANK_STD)
        .collect();
    if let Some(first) = blank.first() {
        let all = blank.len() == camera.frames.len();
        lint.flag(
            camera.episode,
            Some(first.frame),
            format!(
                "{}: {} of {} frames blank (grey level {:.0} everywhere){}",
                camera.camera,
                blank.len(),
                camera.frames.len(),
                first.mean,
                if all {
                    ": the camera shows nothing"
                } else {
                    ""
                }
            ),
        );
    }
}

/// Runs of at least `run` identical pictures over which the robot's state changed.
fn frozen(lint: &mut Lint<'_>, camera: &CameraFrames, episode: Option<&EpisodeSeries>, run: usize) {
    let moved = |from: u64, to: u64| -> bool {
        let Some(state) = episode.and_then(|e| e.features.get("observation.state")) else {
            return true;
        };
        let (from, to) = (from as usize, to as usize);
        if to >= state.frames() {
            return false;
        }
        state
            .row(from)
            .iter()
            .zip(state.row(to))
            .any(|(a, b)| (a - b).abs() > 1e-4)
    };
    let frames = &camera.frames;
    let mut start = 0;
    for t in 1..=frames.len() {
        let continues = t < frames.len() && frames[t].hash == frames[start].hash;
        if continues {
            continue;
        }
        let length = t - start;
        // Every frame that repeats the one before is looked at: the run's picture is known.
        let picture = frames[start..t].iter().find(|f| f.seen);
        if length >= run && picture.is_some_and(|f| f.std >= BLANK_STD) {
            let (first, last) = (frames[start].frame, frames[t - 1].frame);
            if moved(first, last) {
                lint.flag(
                    camera.episode,
                    Some(first),
                    format!(
                        "{}: the same picture for {length} frames ({first}..={last}) while the robot moves: a frozen camera",
                        camera.camera
                    ),
                );
                return;
            }
        }
        start = t;
    }
}

/// Compared between consecutive frames whose pictures both cameras' looks hold.
fn swapped(lint: &mut Lint<'_>, a: &CameraFrames, b: &CameraFrames) {
    let both: Vec<(&FrameLook, &FrameLook)> = (a.frames.iter().zip(&b.frames))
        .filter(|(a, b)| a.seen && b.seen)
        .collect();
    for pair in both.windows(2) {
        let ((a0, b0), (a1, b1)) = (pair[0], pair[1]);
        let own = a1.distance(a0) + b1.distance(b0);
        let crossed = a1.distance(b0) + b1.distance(a0);
        if own > 64.0 * 4.0 && crossed < SWAP_FACTOR * own {
            lint.flag(
                a.episode,
                Some(a1.frame),
                format!(
                    "{} and {} trade pictures at this frame: cameras swapped?",
                    a.camera, b.camera
                ),
            );
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dataset, episodes};
    use super::*;
    use crate::export::findings::Findings;

    /// A camera whose picture is a bright square at a moving place on a grey ramp.
    fn camera(episode: u64, name: &str, frames: usize, offset: usize) -> CameraFrames {
        let (w, h) = (32, 32);
        let looks = (0..frames)
            .map(|t| {
                let mut pixels = vec![0u8; w * h];
                // Cameras of odd offsets see the ramp the other way and the square lower down.
                let odd = offset % 2 == 1;
                for (i, p) in pixels.iter_mut().enumerate() {
                    let x = if odd { w - 1 - i % w } else { i % w };
                    *p = (x * 4) as u8;
                }
                let at = (t + offset) % (w - 8);
                let top = 4 + usize::from(odd) * 14;
                for y in top..top + 8 {
                    for x in at..at + 8 {
                        pixels[y * w + x] = 255;
                    }
                }
                FrameLook::of(t as u64, w, h, 1, &pixels)
            })
            .collect();
        CameraFrames {
            episode,
            camera: name.into(),
            shape: (w, h, 1),
            frames: looks,
        }
    }

    fn fired(cameras: &[CameraFrames]) -> Vec<String> {
        let findings = Findings::new(std::path::Path::new("/nonexistent"));
        let mut lint = Lint::new(&findings, "data", 2);
        check(&mut lint, &dataset(), &episodes(2, 20), cameras);
        let report = findings.into_report("lerobot-v3.0", Default::default());
        super::super::testing::fired(&report)
    }

    #[test]
    fn blank_frozen_and_swapped_cameras_are_found_and_moving_ones_are_not() {
        let clean = vec![
            camera(0, "left", 20, 0),
            camera(0, "right", 20, 11),
            camera(1, "left", 20, 5),
            camera(1, "right", 20, 17),
        ];
        assert!(fired(&clean).is_empty());
        let mut blank = clean.clone();
        blank[1].frames[7] = FrameLook::of(7, 32, 32, 1, &[0u8; 32 * 32]);
        assert_eq!(fired(&blank), ["blank-camera"]);
        let mut frozen = clean.clone();
        for t in 8..14 {
            frozen[2].frames[t] = FrameLook {
                frame: t as u64,
                ..frozen[2].frames[7]
            };
        }
        assert_eq!(fired(&frozen), ["frozen-camera"]);
        let mut swapped = clean.clone();
        for t in 10..20 {
            let (a, b) = (swapped[0].frames[t], swapped[1].frames[t]);
            swapped[0].frames[t] = b;
            swapped[1].frames[t] = a;
        }
        assert_eq!(fired(&swapped), ["camera-swap"]);
    }

    /// Frames looked at as PNG frames are: every one hashed, the pictures of some only. A
    /// swap is found between the frames both cameras' pictures are known at, a frozen run
    /// whose first frame was not looked at still by its repeats, and an unseen frame is never
    /// called blank.
    #[test]
    fn sampled_looks_find_the_same_defects() {
        let sampled = |cameras: &[CameraFrames]| -> Vec<CameraFrames> {
            (cameras.iter())
                .map(|c| CameraFrames {
                    frames: (c.frames.iter())
                        .map(|f| match f.frame % LOOK_EVERY {
                            0 => *f,
                            _ => FrameLook::unseen(f.frame, f.hash),
                        })
                        .collect(),
                    ..c.clone()
                })
                .collect()
        };
        let clean = vec![camera(0, "left", 20, 0), camera(0, "right", 20, 11)];
        assert!(fired(&sampled(&clean)).is_empty());
        let mut swapped = clean.clone();
        for t in 10..20 {
            let (a, b) = (swapped[0].frames[t], swapped[1].frames[t]);
            swapped[0].frames[t] = b;
            swapped[1].frames[t] = a;
        }
        assert_eq!(fired(&sampled(&swapped)), ["camera-swap"]);
        // A frozen run from frame 9 (not looked at); its repeats are, as rows.rs looks at them.
        let mut frozen = sampled(&clean);
        let picture = clean[0].frames[9];
        frozen[0].frames[9] = FrameLook::unseen(9, picture.hash);
        for t in 10..16 {
            frozen[0].frames[t] = FrameLook {
                frame: t as u64,
                ..picture
            };
        }
        assert_eq!(fired(&frozen), ["frozen-camera"]);
        let mut unseen = sampled(&clean);
        unseen[1].frames[6] = FrameLook::unseen(6, 1);
        assert!(fired(&unseen).is_empty());
    }

    /// Filtered rows of blank frames (black with sensor noise, one flat colour, unfiltered
    /// grey) are candidates; a rendered scene's are not.
    #[test]
    fn blank_frames_are_candidates_and_scenes_are_not() {
        use crate::media::image::{PngLevel, encode_png};
        use crate::media::png_rows::inflate_rows;
        let mut rng = crate::rng::SplitMix64::new(9);
        let (w, h) = (96, 64);
        let candidate = |png: &[u8]| {
            let mut rows = Vec::new();
            let header = inflate_rows(png, None, &mut rows).expect("inflates");
            could_be_blank(&rows, header.stride(), header.pixel_bytes())
        };
        let noisy_black: Vec<u8> = (0..w * h * 3).map(|_| (rng.next_u64() % 4) as u8).collect();
        let flat: Vec<u8> = [40u8, 90, 160].repeat(w * h);
        // A scene: shaded tissue with vessels and an instrument's edges.
        let scene: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                let vessel = (x + 2 * y) % 23 < 3;
                let tool = x > 60 && y > 20 && y < 30;
                let base = (120 + x / 2 + y) as u8;
                match (vessel, tool) {
                    (_, true) => [200, 200, 210],
                    (true, _) => [base / 2, 20, 30],
                    _ => [base, base / 2 + 30, base / 3],
                }
            })
            .collect();
        for (pixels, blank) in [(&noisy_black, true), (&flat, true), (&scene, false)] {
            let png = encode_png(w, h, 3, pixels, PngLevel::Fast).expect("encode");
            assert_eq!(candidate(&png), blank);
            let look = FrameLook::of(0, w, h, 3, pixels);
            assert_eq!(look.std < BLANK_STD, blank, "std {}", look.std);
        }
        let mut unfiltered = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut unfiltered, w as u32, h as u32);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_filter(png::Filter::NoFilter);
            let mut writer = encoder.write_header().expect("header");
            writer.write_image_data(&flat).expect("data");
        }
        assert!(candidate(&unfiltered));
    }
}
