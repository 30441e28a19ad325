//! Video for image features: AV1 (rav1e, LeRobot's own codec family) or H.264 (openh264), both
//! yuv420p, in MP4 (muxide), without system libraries. One encoder per episode (episodes encode in parallel; every episode starts
//! with an IDR frame), appended to a shared MP4 whose presentation times run on across episodes,
//! so an episode is the span `[from_timestamp, to_timestamp)` of its file.

use crate::media::MediaError;
use muxide::api::{Muxer, MuxerBuilder, VideoCodec};
use openh264::OpenH264API;
use openh264::encoder::{
    Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, RateControlMode,
};
use openh264::formats::{RgbSliceU8, YUVBuffer};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// One encoded frame (Annex B bytes for H.264, OBUs for AV1).
pub use crate::episode::EncodedFrame;
/// The video codec of a dataset (the episode model's [`VideoCodec`](crate::episode::VideoCodec)).
pub use crate::episode::VideoCodec as Codec;

/// BT.601 limited-range RGB to planar YUV 4:2:0 (chroma averaged over 2 x 2 blocks).
pub fn rgb_to_yuv420(rgb: &[u8], width: usize, height: usize) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let (cw, ch) = (width.div_ceil(2), height.div_ceil(2));
    let mut y = vec![0u8; width * height];
    let mut u = vec![0u8; cw * ch];
    let mut v = vec![0u8; cw * ch];
    let luma = |r: i32, g: i32, b: i32| ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16;
    for row in 0..height {
        for col in 0..width {
            let i = (row * width + col) * 3;
            let (r, g, b) = (
                i32::from(rgb[i]),
                i32::from(rgb[i + 1]),
                i32::from(rgb[i + 2]),
            );
            y[row * width + col] = luma(r, g, b).clamp(0, 255) as u8;
        }
    }
    for crow in 0..ch {
        for ccol in 0..cw {
            let (mut r, mut g, mut b, mut n) = (0i32, 0i32, 0i32, 0i32);
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let (row, col) = (crow * 2 + dy, ccol * 2 + dx);
                if row < height && col < width {
                    let i = (row * width + col) * 3;
                    r += i32::from(rgb[i]);
                    g += i32::from(rgb[i + 1]);
                    b += i32::from(rgb[i + 2]);
                    n += 1;
                }
            }
            let (r, g, b) = (r / n.max(1), g / n.max(1), b / n.max(1));
            u[crow * cw + ccol] =
                (((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128).clamp(0, 255) as u8;
            v[crow * cw + ccol] =
                (((112 * r - 94 * g - 18 * b + 128) >> 8) + 128).clamp(0, 255) as u8;
        }
    }
    (y, u, v)
}

/// The OBUs of an AV1 temporal unit: (OBU type, its bytes' range, header included); None when a
/// size field runs past the end. An OBU without a size field runs to the end.
pub fn obus(data: &[u8]) -> Option<Vec<(u8, std::ops::Range<usize>)>> {
    let mut spans = Vec::new();
    let mut i = 0;
    while i < data.len() {
        let header = data[i];
        let obu_type = (header >> 3) & 0x0f;
        let has_extension = header & 0x04 != 0;
        let has_size = header & 0x02 != 0;
        let mut j = i + 1 + usize::from(has_extension);
        let payload = if has_size {
            let (mut value, mut shift) = (0usize, 0);
            loop {
                let byte = data.get(j)?;
                value |= usize::from(byte & 0x7f) << shift;
                j += 1;
                shift += 7;
                if byte & 0x80 == 0 || shift > 56 {
                    break;
                }
            }
            value
        } else {
            data.len().saturating_sub(j)
        };
        let end = j.saturating_add(payload).min(data.len());
        spans.push((obu_type, i..end));
        i = end;
    }
    Some(spans)
}

/// Removes temporal-delimiter OBUs (type 2) from an AV1 packet: MP4 samples must not carry them.
/// A packet that does not parse is returned as it is.
pub fn strip_temporal_delimiters(data: &[u8]) -> Vec<u8> {
    let Some(spans) = obus(data) else {
        return data.to_vec();
    };
    let mut out = Vec::with_capacity(data.len());
    for (_, range) in spans.into_iter().filter(|(kind, _)| *kind != 2) {
        out.extend_from_slice(&data[range]);
    }
    out
}

/// An episode's video encoder fed frame by frame ([`VideoEncoder::push`]), so that an episode
/// need not be held whole: the same packets as [`encode`] of all its frames.
pub struct VideoEncoder {
    inner: Inner,
    width: usize,
    height: usize,
    /// Frames pushed and packets handed out, to check that every frame made one.
    pushed: usize,
    handed: usize,
}

enum Inner {
    Av1(Box<rav1e::Context<u8>>),
    H264(Box<Encoder>),
}

fn av1_error(source: Box<dyn std::error::Error + Send + Sync>) -> MediaError {
    MediaError::Encode {
        what: "AV1".into(),
        source,
    }
}

fn h264_error(e: openh264::Error) -> MediaError {
    MediaError::Encode {
        what: "H.264".into(),
        source: Box::new(e),
    }
}

impl VideoEncoder {
    /// An encoder of `width` x `height` RGB frames at `fps` with `codec` at the quality setting
    /// `quality` (H.264: largest quantiser 0..51; AV1: quantizer 0..255). AV1 runs one encoder
    /// thread (rav1e, low latency); H.264 has rate control off, so quality is steady. Both
    /// start with a key frame and put one every two seconds.
    pub fn new(
        codec: Codec,
        (width, height): (usize, usize),
        fps: u32,
        quality: u32,
    ) -> Result<VideoEncoder, MediaError> {
        if codec == Codec::H264 && (width % 2 == 1 || height % 2 == 1) {
            return Err(MediaError::Encode {
                what: "H.264".into(),
                source: format!("{width}x{height} pixels: 4:2:0 needs an even width and height")
                    .into(),
            });
        }
        let inner = match codec {
            Codec::Av1 => {
                use rav1e::prelude::*;
                let config = EncoderConfig {
                    width,
                    height,
                    time_base: Rational::new(1, u64::from(fps.max(1))),
                    bit_depth: 8,
                    chroma_sampling: ChromaSampling::Cs420,
                    low_latency: true,
                    min_key_frame_interval: 0,
                    max_key_frame_interval: u64::from(fps.max(1)) * 2,
                    quantizer: quality.min(255) as usize,
                    speed_settings: SpeedSettings::from_preset(10),
                    ..Default::default()
                };
                let context: Context<u8> = Config::new()
                    .with_encoder_config(config)
                    .with_threads(1)
                    .new_context()
                    .map_err(|e| av1_error(Box::new(e)))?;
                Inner::Av1(Box::new(context))
            }
            Codec::H264 => {
                let max_qp = quality.min(51) as u8;
                let config = EncoderConfig::new()
                    .rate_control_mode(RateControlMode::Off)
                    .qp(QpRange::new(max_qp.saturating_sub(8), max_qp))
                    .max_frame_rate(FrameRate::from_hz(fps as f32))
                    .skip_frames(false)
                    .scene_change_detect(false)
                    .intra_frame_period(IntraFramePeriod::from_num_frames(fps.max(1) * 2));
                let encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
                    .map_err(h264_error)?;
                Inner::H264(Box::new(encoder))
            }
        };
        Ok(VideoEncoder {
            inner,
            width,
            height,
            pushed: 0,
            handed: 0,
        })
    }

    /// Encodes the next frame (row-major RGB, 3 bytes a pixel); returns the packets ready
    /// (AV1 may hold a few frames back until [`VideoEncoder::finish`]).
    pub fn push(&mut self, rgb: &[u8]) -> Result<Vec<EncodedFrame>, MediaError> {
        let (width, height) = (self.width, self.height);
        self.pushed += 1;
        let mut out = Vec::new();
        match &mut self.inner {
            Inner::Av1(context) => {
                let (y, u, v) = rgb_to_yuv420(rgb, width, height);
                let mut frame = context.new_frame();
                let cw = width.div_ceil(2);
                frame.planes[0].copy_from_raw_u8(&y, width, 1);
                frame.planes[1].copy_from_raw_u8(&u, cw, 1);
                frame.planes[2].copy_from_raw_u8(&v, cw, 1);
                context
                    .send_frame(frame)
                    .map_err(|e| av1_error(Box::new(e)))?;
                drain_av1(context, &mut out)?;
            }
            Inner::H264(encoder) => {
                let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(rgb, (width, height)));
                let bitstream = encoder.encode(&yuv).map_err(h264_error)?;
                let keyframe = matches!(
                    bitstream.frame_type(),
                    openh264::encoder::FrameType::IDR | openh264::encoder::FrameType::I
                );
                let data = bitstream.to_vec();
                if data.is_empty() {
                    return Err(MediaError::Encode {
                        what: "H.264".into(),
                        source: "the encoder skipped a frame".into(),
                    });
                }
                out.push(EncodedFrame { data, keyframe });
            }
        }
        self.handed += out.len();
        Ok(out)
    }

    /// The packets still held; an error unless every frame pushed made one.
    pub fn finish(mut self) -> Result<Vec<EncodedFrame>, MediaError> {
        let mut out = Vec::new();
        if let Inner::Av1(context) = &mut self.inner {
            context.flush();
            while !drain_av1(context, &mut out)? {}
        }
        self.handed += out.len();
        if self.handed != self.pushed {
            return Err(MediaError::Encode {
                what: match self.inner {
                    Inner::Av1(_) => "AV1",
                    Inner::H264(_) => "H.264",
                }
                .into(),
                source: format!("{} frames in, {} packets out", self.pushed, self.handed).into(),
            });
        }
        Ok(out)
    }
}

/// Takes the AV1 packets ready; true once the encoder has nothing more to give.
fn drain_av1(
    context: &mut rav1e::Context<u8>,
    out: &mut Vec<EncodedFrame>,
) -> Result<bool, MediaError> {
    use rav1e::prelude::*;
    loop {
        match context.receive_packet() {
            Ok(packet) => out.push(EncodedFrame {
                data: strip_temporal_delimiters(&packet.data),
                keyframe: packet.frame_type == FrameType::KEY,
            }),
            Err(EncoderStatus::Encoded) => continue,
            Err(EncoderStatus::NeedMoreData) => return Ok(false),
            Err(EncoderStatus::LimitReached) => return Ok(true),
            Err(e) => return Err(av1_error(Box::new(e))),
        }
    }
}

/// Encodes an episode's RGB frames with `codec` at the quality setting `quality` (see
/// [`VideoEncoder::new`]).
pub fn encode(
    codec: Codec,
    frames: &[&[u8]],
    width: usize,
    height: usize,
    fps: u32,
    quality: u32,
) -> Result<Vec<EncodedFrame>, MediaError> {
    let mut encoder = VideoEncoder::new(codec, (width, height), fps, quality)?;
    let mut out = Vec::with_capacity(frames.len());
    for rgb in frames {
        out.extend(encoder.push(rgb)?);
    }
    out.extend(encoder.finish()?);
    Ok(out)
}

/// Encodes an episode's RGB frames as AV1 (8-bit 4:2:0) with one encoder thread.
pub fn encode_av1(
    frames: &[&[u8]],
    width: usize,
    height: usize,
    fps: u32,
    quantizer: usize,
) -> Result<Vec<EncodedFrame>, MediaError> {
    encode(Codec::Av1, frames, width, height, fps, quantizer as u32)
}

/// Encodes an episode's RGB frames (row-major, 3 bytes a pixel) as H.264; `max_qp` bounds the
/// quantiser (0 best .. 51 worst).
pub fn encode_h264(
    frames: &[&[u8]],
    width: usize,
    height: usize,
    fps: u32,
    max_qp: u8,
) -> Result<Vec<EncodedFrame>, MediaError> {
    encode(Codec::H264, frames, width, height, fps, u32::from(max_qp))
}

/// Bytes an MP4 file is written in (muxide writes each sample on its own at `finish`).
const MP4_WRITE_BUFFER_BYTES: usize = 1 << 20;

/// An MP4 file being appended to: the muxer over an open file, and the presentation clock.
pub struct Mp4Writer<W: Write = File> {
    muxer: Muxer<std::io::BufWriter<W>>,
    /// Sample bytes appended so far: what the file will hold besides its boxes.
    sample_bytes: u64,
    /// The file's name, for errors.
    path: PathBuf,
    /// Frames written so far (the next frame's presentation time is `frames / fps`).
    pub frames: u64,
    fps: u32,
}

/// An MP4 error naming the file; an I/O failure (a full disk) stays an I/O error.
fn mp4_error(path: &Path) -> impl Fn(muxide::api::MuxerError) -> MediaError + '_ {
    move |e| match e {
        muxide::api::MuxerError::Io(source) => MediaError::Io {
            path: path.to_path_buf(),
            source,
        },
        other => MediaError::Encode {
            what: format!("MP4 {}", path.display()),
            source: Box::new(other),
        },
    }
}

impl<W: Write> Mp4Writer<W> {
    /// Starts an MP4 in `handle` (a file, or a writer over one); `path` names it in errors.
    pub fn create(
        handle: W,
        path: PathBuf,
        codec: Codec,
        (width, height): (usize, usize),
        fps: u32,
    ) -> Result<Self, MediaError> {
        let output = std::io::BufWriter::with_capacity(MP4_WRITE_BUFFER_BYTES, handle);
        let muxer = MuxerBuilder::new(output)
            .video(
                match codec {
                    Codec::H264 => VideoCodec::H264,
                    Codec::Av1 => VideoCodec::Av1,
                },
                width as u32,
                height as u32,
                f64::from(fps),
            )
            .with_fast_start(false)
            .build()
            .map_err(mp4_error(&path))?;
        Ok(Mp4Writer {
            muxer,
            sample_bytes: 0,
            path,
            frames: 0,
            fps,
        })
    }

    /// Appends an episode's frames; returns its (from, to) timestamps in this file.
    pub fn append(&mut self, frames: &[EncodedFrame]) -> Result<(f64, f64), MediaError> {
        let from = self.frames as f64 / f64::from(self.fps);
        for frame in frames {
            let pts = self.frames as f64 / f64::from(self.fps);
            self.muxer
                .write_video(pts, &frame.data, frame.keyframe)
                .map_err(mp4_error(&self.path))?;
            self.sample_bytes += frame.data.len() as u64;
            self.frames += 1;
        }
        Ok((from, self.frames as f64 / f64::from(self.fps)))
    }

    /// The presentation time after the frames written so far, seconds.
    pub fn time_secs(&self) -> f64 {
        self.frames as f64 / f64::from(self.fps)
    }

    /// The file's size so far, less its boxes: the bytes of the samples appended. muxide keeps
    /// every sample in memory until [`Mp4Writer::finish`], so the file on disk is empty until
    /// then; this is what a rolling rule must count.
    pub fn bytes_written(&self) -> u64 {
        self.sample_bytes
    }

    /// Completes the file (the moov box at the end), writes out what is buffered, and gives
    /// back the handle it was created with.
    pub fn finish(mut self) -> Result<W, MediaError> {
        self.muxer
            .finish_in_place()
            .map_err(mp4_error(&self.path))?;
        (self.muxer.into_writer().into_inner()).map_err(|e| MediaError::Io {
            path: self.path,
            source: e.into_error(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_an_encoder_cannot_take_are_refused_instead_of_aborting() {
        let odd = VideoEncoder::new(Codec::H264, (3, 2), 10, 24).err();
        assert!(odd.is_some_and(|e| e.to_string().contains("H.264")));
        assert!(VideoEncoder::new(Codec::Av1, (3, 2), 10, 80).is_err());
        let mut h264 = VideoEncoder::new(Codec::H264, (16, 16), 10, 24).expect("even");
        let mut packets = h264.push(&[7; 768]).expect("encode");
        packets.extend(h264.finish().expect("finish"));
        assert_eq!(packets.len(), 1);
    }

    #[test]
    fn av1_encodes_every_frame_without_temporal_delimiters() {
        let frames: Vec<Vec<u8>> = (0..6u8)
            .map(|i| {
                (0..64 * 48 * 3)
                    .map(|k| (k as u8).wrapping_add(i * 9))
                    .collect()
            })
            .collect();
        let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
        let encoded = encode_av1(&refs, 64, 48, 5, 80).expect("encode");
        assert_eq!(encoded.len(), 6);
        assert!(encoded[0].keyframe);
        // The first OBU of the keyframe is the sequence header (type 1), not a delimiter.
        assert_eq!((encoded[0].data[0] >> 3) & 0x0f, 1);
        assert!(encoded.iter().all(|f| (f.data[0] >> 3) & 0x0f != 2));
    }

    #[test]
    fn yuv_of_grey_is_neutral() {
        let (y, u, v) = rgb_to_yuv420(&[128u8; 4 * 4 * 3], 4, 4);
        assert!(y.iter().all(|p| *p == 126));
        assert!(u.iter().chain(&v).all(|p| *p == 128));
    }

    #[test]
    fn every_frame_is_encoded_and_the_first_is_a_keyframe() {
        let frames: Vec<Vec<u8>> = (0..7u8)
            .map(|i| vec![i.wrapping_mul(30); 64 * 48 * 3])
            .collect();
        let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
        let encoded = encode_h264(&refs, 64, 48, 5, 24).expect("encode");
        assert_eq!(encoded.len(), 7);
        assert!(encoded[0].keyframe);
        assert!(
            encoded
                .iter()
                .all(|f| f.data.starts_with(&[0, 0, 0, 1]) || f.data.starts_with(&[0, 0, 1]))
        );
        // Deterministic: the same frames give the same bytes.
        let again = encode_h264(&refs, 64, 48, 5, 24).expect("encode");
        assert!(encoded.iter().zip(&again).all(|(a, b)| a.data == b.data));
    }
}
