//! Decoding video samples back to pixels: H.264 with OpenH264's decoder (the `openh264` crate,
//! already built for encoding, from bundled source) into planar YUV 4:2:0, and YUV -> RGB in
//! integer arithmetic (the same bytes on every machine).
//!
//! AV1 with rav1d ([`decode_av1`], in `av1.rs`, the library's only unsafe code: rav1d's public
//! API is dav1d's C API).
//!
//! H.264 Baseline, Main and High (8-bit 4:2:0) and 8-bit 4:2:0 AV1 decode; another profile is
//! refused by name before decoding, never turned into garbage frames. Both decoders are handed
//! only samples whose headers were read first (`sps.rs`: H.264 sequence parameter sets; AV1
//! sequence headers in `av1.rs`), sizes checked against [`MAX_DECODED_SIDE_PX`].

mod av1;

pub mod check;

pub mod color;
mod frame;
mod sps;

pub use av1::{decode_av1, decode_av1_each};

/// The largest frame side decoded, pixels (8K video; larger is refused before allocating).
pub const MAX_DECODED_SIDE_PX: u32 = 8192;

use crate::episode::{EncodedFrame, VideoCodec};
use crate::media::MediaError;
pub use color::ColorSpace;
pub use frame::YuvFrame;
use openh264::OpenH264API;
use openh264::decoder::{DecodedYUV, Decoder, DecoderConfig, Flush};
use openh264::formats::YUVSource;

/// H.264 profiles (`profile_idc` of the sequence parameter set) the decoder is used for: 8-bit
/// 4:2:0. Measured: libx264 (PyAV 15.1) Baseline, Main (CABAC) and High (8x8 transforms)
/// streams without B-frames decode to PyAV's Y/U/V planes bit for bit (B-frames are refused
/// earlier, by the demuxer). High 10, 4:2:2 and 4:4:4 are not 8-bit 4:2:0.
const DECODED_PROFILES: [(u8, &str); 3] = [(66, "Baseline"), (77, "Main"), (100, "High")];

/// The name of an H.264 `profile_idc`.
pub fn h264_profile_name(profile_idc: u8) -> &'static str {
    match profile_idc {
        66 => "Baseline",
        77 => "Main",
        88 => "Extended",
        100 => "High",
        110 => "High 10",
        122 => "High 4:2:2",
        244 => "High 4:4:4 Predictive",
        _ => "unknown",
    }
}

/// The `profile_idc` of the first sequence parameter set in Annex B bytes, if any.
pub fn h264_profile(annex_b: &[u8]) -> Option<u8> {
    let mut at = 0;
    while at + 4 < annex_b.len() {
        if annex_b[at..].starts_with(&[0, 0, 1]) {
            let header = annex_b[at + 3];
            if header & 0x1f == 7 {
                return annex_b.get(at + 4).copied();
            }
            at += 3;
        } else {
            at += 1;
        }
    }
    None
}

fn decode_error(what: &str) -> impl Fn(openh264::Error) -> MediaError + '_ {
    move |e| MediaError::Decode {
        what: what.to_string(),
        source: Box::new(e),
    }
}

/// Copies a decoded picture's planes (which carry stride padding) into a [`YuvFrame`].
fn planes(picture: &DecodedYUV<'_>) -> YuvFrame {
    let (width, height) = picture.dimensions();
    let (y_stride, u_stride, v_stride) = picture.strides();
    let (cw, ch) = (width.div_ceil(2), height.div_ceil(2));
    let tight = |plane: &[u8], stride: usize, w: usize, h: usize| -> Vec<u8> {
        plane
            .chunks(stride)
            .take(h)
            .flat_map(|row| &row[..w.min(row.len())])
            .copied()
            .collect()
    };
    YuvFrame {
        width_px: width as u32,
        height_px: height as u32,
        y: tight(picture.y(), y_stride, width, height),
        u: tight(picture.u(), u_stride, cw, ch),
        v: tight(picture.v(), v_stride, cw, ch),
        color: ColorSpace::default(),
    }
}

/// Decodes an H.264 span (Annex B samples in decode order starting on a keyframe, as
/// [`crate::media::demux::VideoReader::decodable`] returns them), handing each picture to
/// `on_picture` in presentation order (OpenH264 reorders B-frames); returns how many there
/// were. `what` names the stream in errors (file and feature). A profile the decoder is not
/// used for is refused as a usage error naming it; a sequence parameter set declaring pictures
/// over `max_side` on a side is refused before the decoder sees it ([`sps::h264_sps_problem`]).
pub fn decode_h264_each<E: From<MediaError>>(
    samples: &[EncodedFrame],
    what: &str,
    max_side: u32,
    on_picture: &mut dyn FnMut(YuvFrame) -> Result<(), E>,
) -> Result<usize, E> {
    if let Some(profile) = samples.first().and_then(|s| h264_profile(&s.data))
        && !DECODED_PROFILES.iter().any(|(idc, _)| *idc == profile)
    {
        return Err(MediaError::Unsupported(format!(
            "{what} is H.264 {} profile (profile_idc {profile}); surgvla decodes H.264 {} only",
            h264_profile_name(profile),
            DECODED_PROFILES.map(|(_, name)| name).join(", ")
        ))
        .into());
    }
    let error = decode_error(what);
    // Flushing after every sample (the crate's default) would hand out pictures before the
    // B-frames that precede them in presentation order are decoded.
    let config = DecoderConfig::new().flush_after_decode(Flush::NoFlush);
    let mut decoder =
        Decoder::with_api_config(OpenH264API::from_source(), config).map_err(&error)?;
    // The span starts on a keyframe carrying its SPS, whose VUI signals the colour space.
    let color = samples
        .first()
        .and_then(|s| sps::h264_color_space(&s.data))
        .unwrap_or_default();
    let with_color = |picture: &DecodedYUV<'_>| YuvFrame {
        color,
        ..planes(picture)
    };
    let mut count = 0;
    for sample in samples {
        if let Some(problem) = sps::h264_sps_problem(&sample.data, max_side) {
            return Err(MediaError::Decode {
                what: what.to_string(),
                source: problem.into(),
            }
            .into());
        }
        if let Some(picture) = decoder.decode(&sample.data).map_err(&error)? {
            count += 1;
            on_picture(with_color(&picture))?;
        }
    }
    for picture in decoder.flush_remaining().map_err(&error)? {
        count += 1;
        on_picture(with_color(&picture))?;
    }
    Ok(frame::every_sample_decoded(count, samples.len(), what)?)
}

/// [`decode_h264_each`] up to [`MAX_DECODED_SIDE_PX`], the pictures collected.
pub fn decode_h264(samples: &[EncodedFrame], what: &str) -> Result<Vec<YuvFrame>, MediaError> {
    let mut pictures = Vec::with_capacity(samples.len());
    decode_h264_each(samples, what, MAX_DECODED_SIDE_PX, &mut |p| {
        pictures.push(p);
        Ok(())
    })?;
    Ok(pictures)
}

/// Decodes a span of `codec` samples (decode order, from a keyframe), handing each picture to
/// `on_picture` in presentation order; `what` names the stream in errors, frames beyond
/// `max_side` on a side are refused. Returns the number of pictures.
pub fn decode_span_each<E: From<MediaError>>(
    codec: VideoCodec,
    samples: &[EncodedFrame],
    what: &str,
    max_side: u32,
    on_picture: &mut dyn FnMut(YuvFrame) -> Result<(), E>,
) -> Result<usize, E> {
    let mut checked = |picture: YuvFrame| -> Result<(), E> {
        if picture.width_px > max_side || picture.height_px > max_side {
            return Err(MediaError::Decode {
                what: what.to_string(),
                source: format!(
                    "a {}x{} picture, larger than {max_side} a side",
                    picture.width_px, picture.height_px
                )
                .into(),
            }
            .into());
        }
        on_picture(picture)
    };
    match codec {
        VideoCodec::Av1 => decode_av1_each(samples, what, max_side, &mut checked),
        VideoCodec::H264 => decode_h264_each(samples, what, max_side, &mut checked),
    }
}

/// [`decode_span_each`], the pictures collected.
pub fn decode_span(
    codec: VideoCodec,
    samples: &[EncodedFrame],
    what: &str,
    max_side: u32,
) -> Result<Vec<YuvFrame>, MediaError> {
    let mut pictures = Vec::with_capacity(samples.len());
    decode_span_each(codec, samples, what, max_side, &mut |p| {
        pictures.push(p);
        Ok(())
    })?;
    Ok(pictures)
}

/// lerobot's tolerance between a row's timestamp and the frame it gets, seconds
/// (`decode_video_frames(..., tolerance_s=1e-4)`).
pub const FRAME_TOLERANCE_SECS: f64 = 1e-4;

/// A query time no frame lies within the tolerance of.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameMiss {
    /// Which query, and its time (seconds).
    pub query: usize,
    pub query_secs: f64,
    /// How far the nearest frame is (infinite when there is none).
    pub distance_secs: f64,
}

/// Frames as lerobot selects them: for each query time, the index of the frame whose
/// presentation time is nearest (the earlier one on a tie, as `argmin` takes the first), which
/// must lie strictly within `tolerance_secs`. `frame_secs` is in presentation order.
pub fn nearest_frames(
    frame_secs: &[f64],
    query_secs: &[f64],
    tolerance_secs: f64,
) -> Result<Vec<usize>, FrameMiss> {
    query_secs
        .iter()
        .enumerate()
        .map(|(query, &q)| {
            let after = frame_secs.partition_point(|t| *t < q);
            let candidates = [
                after.checked_sub(1),
                (after < frame_secs.len()).then_some(after),
            ];
            let best = candidates
                .into_iter()
                .flatten()
                .map(|i| (i, (frame_secs[i] - q).abs()))
                .fold(None, |best: Option<(usize, f64)>, (i, d)| match best {
                    Some((_, best_d)) if best_d <= d => best,
                    _ => Some((i, d)),
                });
            match best {
                Some((i, d)) if d < tolerance_secs => Ok(i),
                other => Err(FrameMiss {
                    query,
                    query_secs: q,
                    distance_secs: other.map_or(f64::INFINITY, |(_, d)| d),
                }),
            }
        })
        .collect()
}

/// YUV 4:2:0 to RGB (3 bytes a pixel) in the frame's colour space ([`ColorSpace`]: BT.601
/// limited range unless the stream signals otherwise), each chroma sample covering its 2 x 2
/// block, in 8-bit fixed point. None when the planes' sizes disagree with the frame's
/// dimensions.
pub fn rgb_from_yuv420(frame: &YuvFrame) -> Option<Vec<u8>> {
    let (width, height) = (frame.width_px as usize, frame.height_px as usize);
    let (cw, ch) = (width.div_ceil(2), height.div_ceil(2));
    if frame.y.len() != width * height || frame.u.len() != cw * ch || frame.v.len() != cw * ch {
        return None;
    }
    let mut rgb = Vec::with_capacity(width * height * 3);
    for row in 0..height {
        for col in 0..width {
            let chroma = (row / 2) * cw + col / 2;
            rgb.extend_from_slice(&frame.color.rgb(
                frame.y[row * width + col],
                frame.u[chroma],
                frame.v[chroma],
            ));
        }
    }
    Some(rgb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::video::{encode_h264, rgb_to_yuv420};

    /// The mean absolute difference of two images' bytes (what a lossy codec keeps close).
    pub(super) fn mean_difference(source: &[u8], decoded: &[u8]) -> f64 {
        assert_eq!(source.len(), decoded.len());
        let sum: f64 = source
            .iter()
            .zip(decoded)
            .map(|(a, b)| f64::from(a.abs_diff(*b)))
            .sum();
        sum / decoded.len() as f64
    }

    /// A moving gradient, `frames` frames of `width` x `height` RGB.
    fn clip(frames: usize, width: usize, height: usize) -> Vec<Vec<u8>> {
        (0..frames)
            .map(|t| {
                (0..width * height)
                    .flat_map(|i| {
                        let (x, y) = (i % width, i / width);
                        [(x * 4 + t * 3) as u8, (y * 5) as u8, ((x + y) * 2) as u8]
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn limited_range_extremes_and_grey_convert_exactly() {
        let frame = |y: u8| YuvFrame {
            width_px: 2,
            height_px: 2,
            y: vec![y; 4],
            u: vec![128],
            v: vec![128],
            color: ColorSpace::default(),
        };
        assert_eq!(rgb_from_yuv420(&frame(16)), Some(vec![0; 12]));
        assert_eq!(rgb_from_yuv420(&frame(235)), Some(vec![255; 12]));
        assert_eq!(rgb_from_yuv420(&frame(126)), Some(vec![128; 12]));
        // Planes that disagree with the dimensions are refused, never indexed past their end.
        let short = YuvFrame {
            u: Vec::new(),
            ..frame(16)
        };
        assert_eq!(rgb_from_yuv420(&short), None);
        // The encoder's matrix and ours are inverses up to rounding.
        let rgb: Vec<u8> = (0..16).flat_map(|i| [i * 16, 200 - i * 8, 90]).collect();
        let (y, u, v) = rgb_to_yuv420(&rgb, 4, 4);
        let back = rgb_from_yuv420(&YuvFrame {
            width_px: 4,
            height_px: 4,
            y,
            u,
            v,
            color: ColorSpace::default(),
        })
        .expect("planes");
        let worst = rgb.iter().zip(&back).map(|(a, b)| a.abs_diff(*b)).max();
        assert!(worst <= Some(40), "{worst:?}");
    }

    #[test]
    fn our_h264_decodes_frame_for_frame_near_the_source() {
        let (width, height) = (64, 48);
        let frames = clip(12, width, height);
        let slices: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
        let encoded = encode_h264(&slices, width, height, 10, 18).expect("encode");
        assert_eq!(h264_profile(&encoded[0].data), Some(66));
        let decoded = decode_h264(&encoded, "test.mp4").expect("decode");
        assert_eq!(decoded.len(), frames.len());
        for (source, picture) in frames.iter().zip(&decoded) {
            assert_eq!((picture.width_px, picture.height_px), (64, 48));
            let rgb = rgb_from_yuv420(picture).expect("planes");
            let mean = mean_difference(source, &rgb);
            assert!(mean < 4.0, "mean difference {mean}");
        }
        // Decoding is deterministic: the same planes twice.
        assert_eq!(decode_h264(&encoded, "test.mp4").expect("decode"), decoded);
    }

    #[test]
    fn frames_are_picked_by_nearest_presentation_time_within_the_tolerance() {
        let times: Vec<f64> = (0..5).map(|i| f64::from(i) / 30.0).collect();
        // Exact times, and times a float rounding away (v3.0 adds from_timestamp).
        let queries = [0.0, 2.0 / 30.0 + 3e-5, 4.0 / 30.0 - 3e-5, 1.0 / 30.0];
        assert_eq!(
            nearest_frames(&times, &queries, FRAME_TOLERANCE_SECS),
            Ok(vec![0, 2, 4, 1])
        );
        // Half-way between two frames is far outside 1e-4 s.
        let miss = nearest_frames(&times, &[0.5 / 30.0], FRAME_TOLERANCE_SECS).expect_err("miss");
        assert_eq!(miss.query, 0);
        assert!((miss.distance_secs - 0.5 / 30.0).abs() < 1e-12);
        // At exactly the tolerance it misses (lerobot requires min < tolerance_s).
        assert!(nearest_frames(&[0.0], &[0.5], 0.5).is_err());
        // On a tie the earlier frame wins; NaN and no frames miss.
        assert_eq!(nearest_frames(&[0.0, 1.0], &[0.5], 1.0), Ok(vec![0]));
        assert!(nearest_frames(&times, &[f64::NAN], 1.0).is_err());
        let none = nearest_frames(&[], &[0.0], 1.0).expect_err("no frames");
        assert_eq!(none.distance_secs, f64::INFINITY);
    }

    /// A fixture file's pictures as PyAV 15.1 decoded them: presentation time and the CRC-32C
    /// of the Y, U and V planes (tight, in that order), from `<name>.planes`.
    fn pyav_planes(name: &str) -> Vec<(f64, u32)> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/video")
            .join(format!("{name}.planes"));
        std::fs::read_to_string(path)
            .expect("fixture")
            .lines()
            .map(|line| {
                let (secs, crc) = line.split_once(' ').expect("two fields");
                (
                    secs.parse().expect("secs"),
                    u32::from_str_radix(crc, 16).expect("crc"),
                )
            })
            .collect()
    }

    /// Demuxes and decodes a fixture file written by PyAV 15.1 (its own FFmpeg encoders) and
    /// compares every picture with PyAV's decoding of it, bit for bit, with its time.
    fn decodes_like_pyav(name: &str, codec: VideoCodec, reorders: bool) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/video")
            .join(format!("{name}.mp4"));
        let mut reader = crate::media::demux::VideoReader::open(&path).expect("open");
        assert_eq!((reader.codec, reader.reorders), (codec, reorders));
        let span = reader
            .decodable(f64::NEG_INFINITY, f64::INFINITY)
            .expect("span");
        let pictures = decode_span(codec, &span.samples, name, 4096).expect("decode");
        let ours: Vec<(f64, u32)> = span
            .picture_secs
            .iter()
            .zip(&pictures)
            .map(|(secs, p)| (*secs, crc32c::crc32c(&[&p.y[..], &p.u, &p.v].concat())))
            .collect();
        let theirs = pyav_planes(name);
        assert_eq!(ours.len(), theirs.len());
        for ((ours_secs, ours_crc), (their_secs, their_crc)) in ours.iter().zip(&theirs) {
            assert!(
                (ours_secs - their_secs).abs() < 1e-6,
                "{ours_secs} {their_secs}"
            );
            assert_eq!(ours_crc, their_crc, "at {their_secs} s");
        }
        if reorders {
            // Copying a stream that reorders frames is refused; decoding it is not.
            assert!(reader.span(f64::NEG_INFINITY, f64::INFINITY).is_err());
        }
    }

    #[test]
    fn libx264_high_profile_with_b_frames_decodes_to_pyavs_planes() {
        decodes_like_pyav("x264_high_bframes", VideoCodec::H264, true);
    }

    #[test]
    fn libsvtav1_decodes_to_pyavs_planes() {
        decodes_like_pyav("svtav1_g2", VideoCodec::Av1, false);
    }

    #[test]
    fn other_profiles_are_refused_by_name() {
        use crate::error::HasKind as _;
        // An SPS NAL of High 10 profile (profile_idc 110) in front of a keyframe.
        let sample = EncodedFrame {
            data: vec![0, 0, 0, 1, 0x67, 110, 0, 30, 0xff],
            keyframe: true,
        };
        let error = decode_h264(&[sample], "videos/cam/file-000.mp4").expect_err("refused");
        assert_eq!(error.kind(), crate::error::ErrorKind::Usage);
        assert!(
            error.to_string().contains("H.264 High 10 profile"),
            "{error}"
        );
    }
}
