//! Video for image features: H.264 (openh264, yuv420p) in MP4 (muxide), in pure Rust without
//! system libraries. One encoder per episode (episodes encode in parallel; every episode starts
//! with an IDR frame), appended to a shared MP4 whose presentation times run on across episodes,
//! so an episode is the span `[from_timestamp, to_timestamp)` of its file.

use crate::export::ExportError;
use muxide::api::{Muxer, MuxerBuilder, VideoCodec};
use openh264::OpenH264API;
use openh264::encoder::{
    Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, RateControlMode,
};
use openh264::formats::{RgbSliceU8, YUVBuffer};
use std::fs::File;
use std::path::{Path, PathBuf};

/// One encoded frame (Annex B bytes).
#[derive(Clone, Debug)]
pub struct EncodedFrame {
    pub data: Vec<u8>,
    pub keyframe: bool,
}

/// Encodes an episode's RGB frames (row-major, 3 bytes a pixel) as H.264.
/// `max_qp` bounds the quantiser (0 best .. 51 worst): rate control is off, quality is steady.
pub fn encode_h264(
    frames: &[&[u8]],
    width: usize,
    height: usize,
    fps: u32,
    max_qp: u8,
) -> Result<Vec<EncodedFrame>, ExportError> {
    let encode_error = |e: openh264::Error| ExportError::Encode {
        what: "H.264".into(),
        message: e.to_string(),
    };
    let max_qp = max_qp.min(51);
    let config = EncoderConfig::new()
        .rate_control_mode(RateControlMode::Off)
        .qp(QpRange::new(max_qp.saturating_sub(8), max_qp))
        .max_frame_rate(FrameRate::from_hz(fps as f32))
        .skip_frames(false)
        .scene_change_detect(false)
        .intra_frame_period(IntraFramePeriod::from_num_frames(fps.max(1) * 2));
    let mut encoder =
        Encoder::with_api_config(OpenH264API::from_source(), config).map_err(encode_error)?;
    let mut out = Vec::with_capacity(frames.len());
    for rgb in frames {
        let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(rgb, (width, height)));
        let bitstream = encoder.encode(&yuv).map_err(encode_error)?;
        let keyframe = matches!(
            bitstream.frame_type(),
            openh264::encoder::FrameType::IDR | openh264::encoder::FrameType::I
        );
        let data = bitstream.to_vec();
        if data.is_empty() {
            return Err(ExportError::Encode {
                what: "H.264".into(),
                message: "the encoder skipped a frame".into(),
            });
        }
        out.push(EncodedFrame { data, keyframe });
    }
    Ok(out)
}

/// An MP4 file being appended to.
pub struct VideoFile {
    muxer: Muxer<File>,
    temporary: PathBuf,
    pub path: PathBuf,
    pub chunk: u64,
    pub file: u64,
    /// Frames written so far (the next frame's presentation time is `frames / fps`).
    pub frames: u64,
    fps: u32,
}

impl VideoFile {
    pub fn create(
        path: PathBuf,
        chunk: u64,
        file: u64,
        width: usize,
        height: usize,
        fps: u32,
    ) -> Result<Self, ExportError> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let temporary = path.with_file_name(format!(".{name}.partial"));
        let handle = File::create(&temporary).map_err(ExportError::io(&temporary))?;
        let muxer = MuxerBuilder::new(handle)
            .video(
                VideoCodec::H264,
                width as u32,
                height as u32,
                f64::from(fps),
            )
            .with_fast_start(false)
            .build()
            .map_err(|e| ExportError::Encode {
                what: format!("MP4 {}", path.display()),
                message: e.to_string(),
            })?;
        Ok(VideoFile {
            muxer,
            temporary,
            path,
            chunk,
            file,
            frames: 0,
            fps,
        })
    }

    /// Appends an episode's frames; returns its (from, to) timestamps in this file.
    pub fn append(&mut self, frames: &[EncodedFrame]) -> Result<(f64, f64), ExportError> {
        let from = self.frames as f64 / f64::from(self.fps);
        for frame in frames {
            let pts = self.frames as f64 / f64::from(self.fps);
            self.muxer
                .write_video(pts, &frame.data, frame.keyframe)
                .map_err(|e| ExportError::Encode {
                    what: format!("MP4 {}", self.path.display()),
                    message: e.to_string(),
                })?;
            self.frames += 1;
        }
        Ok((from, self.frames as f64 / f64::from(self.fps)))
    }

    /// Bytes written so far.
    pub fn bytes(&self) -> u64 {
        std::fs::metadata(&self.temporary)
            .map(|m| m.len())
            .unwrap_or(0)
    }

    /// Completes the file and gives it its final name.
    pub fn finish(self) -> Result<u64, ExportError> {
        let path = self.path.clone();
        self.muxer.finish().map_err(|e| ExportError::Encode {
            what: format!("MP4 {}", path.display()),
            message: e.to_string(),
        })?;
        std::fs::rename(&self.temporary, &path).map_err(ExportError::io(&path))?;
        Ok(std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0))
    }
}

/// The video path of a feature's file.
pub fn video_path(root: &Path, key: &str, chunk: u64, file: u64) -> PathBuf {
    root.join(format!("videos/{key}/chunk-{chunk:03}/file-{file:03}.mp4"))
}

#[cfg(test)]
mod tests {
    use super::*;

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
