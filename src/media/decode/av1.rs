//! AV1 decoding with rav1d (the Rust port of dav1d), through its C API: the only unsafe code in
//! the library, kept to this file. One decoder per span, drained after every temporal unit:
//! pictures come out in order, one per unit (two frame threads, for rav1d's error path: see
//! [`Decoder::open`]).

#![allow(unsafe_code)]

use super::color::ColorSpace;
use super::frame::YuvFrame;
use crate::episode::EncodedFrame;
use crate::media::MediaError;
use rav1d::include::dav1d::data::Dav1dData;
use rav1d::include::dav1d::dav1d::{Dav1dContext, Dav1dSettings};
use rav1d::include::dav1d::headers::DAV1D_PIXEL_LAYOUT_I420;
use rav1d::include::dav1d::picture::Dav1dPicture;
use rav1d::src::lib::{
    dav1d_close, dav1d_data_create, dav1d_data_unref, dav1d_default_settings, dav1d_get_picture,
    dav1d_open, dav1d_picture_unref, dav1d_send_data,
};
use std::ptr::NonNull;

/// dav1d's "try again" result: `-EAGAIN`.
const AGAIN: i32 = -11;
/// dav1d's "out of memory" result: `-ENOMEM`.
const NO_MEMORY: i32 = -12;

/// Why a stream did not decode: a dav1d error code, or a picture of another bit depth or
/// chroma layout than 8-bit 4:2:0 (ours to refuse, not dav1d's).
enum Failure {
    Code(i32),
    Layout,
}

/// An open decoder, closed on drop.
struct Decoder(Option<Dav1dContext>);

impl Drop for Decoder {
    fn drop(&mut self) {
        // SAFETY: the context came from dav1d_open and is closed once (dav1d_close sets it to
        // None).
        unsafe { dav1d_close(Some(NonNull::from(&mut self.0))) }
    }
}

impl Decoder {
    /// A decoder refusing frames of more than `max_pixels` pixels.
    fn open(max_pixels: u32) -> Result<Self, i32> {
        let mut settings = std::mem::MaybeUninit::<Dav1dSettings>::uninit();
        // SAFETY: dav1d_default_settings writes every field of the settings it is given.
        let mut settings = unsafe {
            dav1d_default_settings(NonNull::new_unchecked(settings.as_mut_ptr()));
            settings.assume_init()
        };
        // Two frame contexts, not one: with one, rav1d 1.1.0 aborts the process on any frame
        // that fails to decode (its error path unwraps a header it already dropped;
        // memorysafety/rav1d#1497). `send` drains after every unit, so pictures still come
        // out in order, one per unit, and an error names its unit.
        settings.n_threads = 2;
        settings.max_frame_delay = 2;
        settings.frame_size_limit = max_pixels;
        // No logging: a damaged stream is reported once, as an error naming its file.
        // SAFETY: dav1d's logger is a cookie and a callback, both nullable pointers (repr(C)
        // Options of pointer types): all zeros is "no callback", which disables logging.
        settings.logger = unsafe { std::mem::zeroed() };
        let mut context = None;
        // SAFETY: both pointers are to live locals; dav1d_open reads the settings and writes
        // the context.
        let result = unsafe {
            dav1d_open(
                Some(NonNull::from(&mut context)),
                Some(NonNull::from(&mut settings)),
            )
        };
        match (result.0, context) {
            (0, Some(context)) => Ok(Decoder(Some(context))),
            (code, _) => Err(code.min(-1)),
        }
    }

    /// Hands one temporal unit to the decoder, collecting every picture it gives meanwhile.
    fn send(&mut self, bytes: &[u8], out: &mut Vec<YuvFrame>) -> Result<(), Failure> {
        let mut data = Dav1dData::default();
        // SAFETY: dav1d_data_create allocates `bytes.len()` bytes owned by `data` and returns
        // them (null on failure); they are written in full before being sent.
        unsafe {
            let buffer = dav1d_data_create(Some(NonNull::from(&mut data)), bytes.len());
            if buffer.is_null() {
                return Err(Failure::Code(NO_MEMORY));
            }
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), buffer, bytes.len());
        }
        let result = loop {
            // SAFETY: the context is open; `data` is a live Dav1dData from dav1d_data_create.
            let sent = unsafe { dav1d_send_data(self.0, Some(NonNull::from(&mut data))) }.0;
            if sent != 0 && sent != AGAIN {
                break Err(Failure::Code(sent));
            }
            if let Err(code) = self.drain(out) {
                break Err(code);
            }
            if data.sz == 0 {
                // A second call with nothing new sent makes the decoder finish the frames in
                // flight (its drain): one picture out per temporal unit, an error at its unit.
                break self.drain(out);
            }
        };
        if data.sz > 0 {
            // SAFETY: `data` still holds (part of) its buffer, released once here.
            unsafe { dav1d_data_unref(Some(NonNull::from(&mut data))) }
        }
        result
    }

    /// Takes every picture the decoder has ready.
    fn drain(&mut self, out: &mut Vec<YuvFrame>) -> Result<(), Failure> {
        loop {
            let mut picture = Dav1dPicture::default();
            // SAFETY: the context is open; `picture` is a live local it writes to.
            let got = unsafe { dav1d_get_picture(self.0, Some(NonNull::from(&mut picture))) }.0;
            if got == AGAIN {
                return Ok(());
            }
            if got != 0 {
                return Err(Failure::Code(got));
            }
            let frame = planes(&picture);
            // SAFETY: the picture came from dav1d_get_picture and is released once.
            unsafe { dav1d_picture_unref(Some(NonNull::from(&mut picture))) }
            out.push(frame?);
        }
    }
}

/// Copies an 8-bit 4:2:0 picture's planes (with their strides) into a [`YuvFrame`].
fn planes(picture: &Dav1dPicture) -> Result<YuvFrame, Failure> {
    let parameters = &picture.p;
    if parameters.bpc != 8 || parameters.layout != DAV1D_PIXEL_LAYOUT_I420 {
        return Err(Failure::Layout);
    }
    let (width, height) = (parameters.w.max(0) as usize, parameters.h.max(0) as usize);
    let (cw, ch) = (width.div_ceil(2), height.div_ceil(2));
    let copy = |plane: usize, stride: isize, w: usize, h: usize| -> Result<Vec<u8>, Failure> {
        // A 4:2:0 picture has all three planes.
        let base = picture.data[plane].ok_or(Failure::Layout)?;
        let mut out = Vec::with_capacity(w * h);
        for row in 0..h {
            // SAFETY: dav1d's plane `plane` holds `h` rows of at least `w` bytes, `stride`
            // bytes apart, while the picture is referenced.
            let line = unsafe {
                std::slice::from_raw_parts(
                    base.as_ptr().cast::<u8>().offset(row as isize * stride),
                    w,
                )
            };
            out.extend_from_slice(line);
        }
        Ok(out)
    };
    // SAFETY: a picture from dav1d_get_picture references its sequence header while it is
    // referenced itself.
    let color = picture
        .seq_hdr
        .map(|header| unsafe { header.as_ref() })
        .map(|header| ColorSpace::from_h273(header.mtrx, header.color_range != 0))
        .unwrap_or_default();
    Ok(YuvFrame {
        width_px: width as u32,
        height_px: height as u32,
        y: copy(0, picture.stride[0], width, height)?,
        u: copy(1, picture.stride[1], cw, ch)?,
        v: copy(2, picture.stride[1], cw, ch)?,
        color,
    })
}

/// Decodes an AV1 span (temporal units starting on a keyframe, as
/// [`crate::media::demux::VideoReader::decodable`] returns them), handing each picture to
/// `on_picture` as it comes out (so a long span never holds more than a few); returns how many
/// there were. `what` names the stream in errors. Frames over `max_side` x `max_side` are
/// refused by the decoder before it allocates them; other than 8-bit 4:2:0 is refused as a
/// usage error.
pub fn decode_av1_each<E: From<MediaError>>(
    samples: &[EncodedFrame],
    what: &str,
    max_side: u32,
    on_picture: &mut dyn FnMut(YuvFrame) -> Result<(), E>,
) -> Result<usize, E> {
    let failed = |failure: Failure| match failure {
        Failure::Code(code) => MediaError::Decode {
            what: what.to_string(),
            source: format!("rav1d error {code}").into(),
        },
        Failure::Layout => MediaError::Unsupported(format!(
            "{what} is AV1 of another bit depth or chroma layout than 8-bit 4:2:0, which surgvla does not decode"
        )),
    };
    let mut decoder = Decoder::open(max_side.saturating_mul(max_side))
        .map_err(|code| failed(Failure::Code(code)))?;
    let mut out = Vec::new();
    let mut count = 0;
    let mut hand_over = |out: &mut Vec<YuvFrame>| -> Result<(), E> {
        for picture in out.drain(..) {
            count += 1;
            on_picture(picture)?;
        }
        Ok(())
    };
    let mut sequence_header_seen = false;
    for sample in samples {
        let max_pixels = u64::from(max_side) * u64::from(max_side);
        let problem = sequence_header_problem(&sample.data, max_pixels, &mut sequence_header_seen);
        if let Some(problem) = problem {
            return Err(MediaError::Decode {
                what: what.to_string(),
                source: problem.into(),
            }
            .into());
        }
        decoder.send(&sample.data, &mut out).map_err(failed)?;
        hand_over(&mut out)?;
    }
    decoder.drain(&mut out).map_err(failed)?;
    hand_over(&mut out)?;
    Ok(super::frame::every_sample_decoded(
        count,
        samples.len(),
        what,
    )?)
}

/// Reads AV1 bits most significant first.
struct Bits<'a> {
    data: &'a [u8],
    position: usize,
}

impl Bits<'_> {
    fn read(&mut self, count: u32) -> Option<u64> {
        let mut value = 0u64;
        for _ in 0..count {
            let byte = self.data.get(self.position / 8)?;
            let bit = (byte >> (7 - self.position % 8)) & 1;
            value = (value << 1) | u64::from(bit);
            self.position += 1;
        }
        Some(value)
    }

    fn flag(&mut self) -> Option<bool> {
        self.read(1).map(|bit| bit == 1)
    }

    /// An unsigned variable-length code (`uvlc()` of the AV1 specification).
    fn uvlc(&mut self) -> Option<u64> {
        let mut zeros = 0;
        while !self.flag()? {
            zeros += 1;
            if zeros >= 32 {
                return Some(u64::from(u32::MAX));
            }
        }
        Some(self.read(zeros)? + (1u64 << zeros) - 1)
    }
}

/// The largest frame (width, height) a sequence header OBU (`obu`: header and payload, as
/// `video::obus` spans it) allows, read as the AV1 specification's `sequence_header_obu()`
/// lays it out; None when it ends early.
pub(crate) fn sequence_header_max_size(obu: &[u8]) -> Option<(u64, u64)> {
    let header = *obu.first()?;
    let mut start = 1 + usize::from(header & 0x04 != 0);
    if header & 0x02 != 0 {
        // The payload's size: leb128.
        while obu.get(start)? & 0x80 != 0 {
            start += 1;
        }
        start += 1;
    }
    let mut bits = Bits {
        data: obu.get(start..)?,
        position: 0,
    };
    bits.read(3)?; // seq_profile
    bits.read(1)?; // still_picture
    if bits.flag()? {
        // reduced_still_picture_header: one operating point, its level.
        bits.read(5)?;
    } else {
        let mut buffer_delay_bits = 0;
        let timing_info = bits.flag()?;
        let mut decoder_model_info = false;
        if timing_info {
            bits.read(32)?;
            bits.read(32)?;
            if bits.flag()? {
                bits.uvlc()?;
            }
            decoder_model_info = bits.flag()?;
            if decoder_model_info {
                buffer_delay_bits = bits.read(5)? as u32 + 1;
                bits.read(32)?;
                bits.read(5)?;
                bits.read(5)?;
            }
        }
        let initial_display_delay = bits.flag()?;
        let operating_points = bits.read(5)? + 1;
        for _ in 0..operating_points {
            bits.read(12)?; // operating_point_idc
            if bits.read(5)? > 7 {
                bits.read(1)?; // seq_tier
            }
            if decoder_model_info && bits.flag()? {
                bits.read(buffer_delay_bits)?;
                bits.read(buffer_delay_bits)?;
                bits.read(1)?;
            }
            if initial_display_delay && bits.flag()? {
                bits.read(4)?;
            }
        }
    }
    let width_bits = bits.read(4)? as u32 + 1;
    let height_bits = bits.read(4)? as u32 + 1;
    let width = bits.read(width_bits)? + 1;
    let height = bits.read(height_bits)? + 1;
    Some((width, height))
}

/// Why the OBUs in `data` (one temporal unit) must not be given to the decoder: a sequence
/// header asking for frames larger than `max_pixels` (the decoder sizes its buffers from it
/// before any frame header is checked against its limit) or cut short, or a frame before any
/// sequence header of the stream (`seen`, kept across samples: rav1d aborts the process on
/// one).
fn sequence_header_problem(data: &[u8], max_pixels: u64, seen: &mut bool) -> Option<String> {
    /// OBU types: frame header, frame, redundant frame header, tile group, tile list.
    const FRAME_OBUS: [u8; 5] = [3, 6, 7, 4, 8];
    let Some(spans) = crate::media::video::obus(data) else {
        return Some("an OBU's size is cut short".to_string());
    };
    for (kind, range) in &spans {
        if *kind == 1 {
            match sequence_header_max_size(&data[range.clone()]) {
                None => return Some("a sequence header ends early".to_string()),
                Some((w, h)) if w.saturating_mul(h) > max_pixels => {
                    return Some(format!(
                        "a sequence header declares frames up to {w} x {h}, more than the {max_pixels} pixels surgvla decodes"
                    ));
                }
                Some(_) => *seen = true,
            }
        } else if FRAME_OBUS.contains(kind) && !*seen {
            return Some("a frame comes before any sequence header".to_string());
        }
    }
    None
}

/// [`decode_av1_each`], the pictures collected.
pub fn decode_av1(
    samples: &[EncodedFrame],
    what: &str,
    max_side: u32,
) -> Result<Vec<YuvFrame>, MediaError> {
    let mut pictures = Vec::with_capacity(samples.len());
    decode_av1_each(samples, what, max_side, &mut |p| {
        pictures.push(p);
        Ok(())
    })?;
    Ok(pictures)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::decode::rgb_from_yuv420;
    use crate::media::decode::tests::mean_difference;
    use crate::media::video::encode_av1;

    #[test]
    fn our_av1_decodes_frame_for_frame_near_the_source() {
        let (width, height) = (64, 48);
        let frames: Vec<Vec<u8>> = (0..8)
            .map(|t| {
                (0..width * height)
                    .flat_map(|i| {
                        let (x, y) = (i % width, i / width);
                        [(x * 4 + t * 3) as u8, (y * 5) as u8, 90]
                    })
                    .collect()
            })
            .collect();
        let slices: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
        let encoded = encode_av1(&slices, width, height, 10, 40).expect("encode");
        let decoded = decode_av1(&encoded, "test.mp4", 8192).expect("decode");
        assert_eq!(decoded.len(), frames.len());
        for (source, picture) in frames.iter().zip(&decoded) {
            assert_eq!((picture.width_px, picture.height_px), (64, 48));
            let rgb = rgb_from_yuv420(picture).expect("planes");
            let mean = mean_difference(source, &rgb);
            assert!(mean < 4.0, "mean difference {mean}");
        }
        assert_eq!(
            decode_av1(&encoded, "test.mp4", 8192).expect("again"),
            decoded
        );
        // A limit below the frame's size is refused, not decoded.
        assert!(decode_av1(&encoded, "test.mp4", 32).is_err());
        // Garbage is an error naming the stream, never a crash.
        let garbage = [EncodedFrame {
            data: vec![0x12, 0x00, 0x0a, 0xff, 0xff, 0xff],
            keyframe: true,
        }];
        let error = decode_av1(&garbage, "bad.mp4", 8192).expect_err("refused");
        assert!(error.to_string().contains("bad.mp4"), "{error}");
    }

    /// A sequence header OBU (reduced still-picture form) declaring frames up to `w` x `h`.
    fn forged_sequence_header(w: u64, h: u64) -> Vec<u8> {
        let mut bits: Vec<u8> = Vec::new();
        let mut push = |value: u64, count: u32| {
            for k in (0..count).rev() {
                bits.push(((value >> k) & 1) as u8);
            }
        };
        push(0, 3); // seq_profile
        push(1, 1); // still_picture
        push(1, 1); // reduced_still_picture_header
        push(0, 5); // seq_level_idx
        push(15, 4); // frame_width_bits_minus_1: 16 bits
        push(15, 4);
        push(w - 1, 16);
        push(h - 1, 16);
        let payload: Vec<u8> = bits
            .chunks(8)
            .map(|c| {
                c.iter()
                    .enumerate()
                    .fold(0u8, |b, (k, bit)| b | (bit << (7 - k)))
            })
            .collect();
        let mut obu = vec![(1 << 3) | 0x02, payload.len() as u8];
        obu.extend(payload);
        obu
    }

    /// The sizes our encoder's sequence headers declare are read back; a header rewritten to
    /// 8192 x 8192 (rav1d aborted the process on it) is refused before the decoder sees it,
    /// with an error naming the stream.
    #[test]
    fn sequence_headers_declaring_huge_frames_are_refused_before_decoding() {
        let frame = vec![90u8; 64 * 48 * 3];
        let encoded = encode_av1(&[frame.as_slice()], 64, 48, 10, 40).expect("encode");
        let data = &encoded[0].data;
        let spans = crate::media::video::obus(data).expect("obus");
        let (_, header) = spans.iter().find(|(kind, _)| *kind == 1).expect("header");
        assert_eq!(
            sequence_header_max_size(&data[header.clone()]),
            Some((64, 48))
        );
        assert_eq!(
            sequence_header_max_size(&forged_sequence_header(8192, 8192)),
            Some((8192, 8192))
        );
        let mut forged = encoded.clone();
        forged[0].data = [forged_sequence_header(8192, 8192), data.clone()].concat();
        let error = decode_av1(&forged, "forged.mp4", 4096).expect_err("refused");
        let text = format!(
            "{error}: {}",
            std::error::Error::source(&error).map_or(String::new(), |s| s.to_string())
        );
        assert!(
            text.contains("forged.mp4") && text.contains("8192 x 8192"),
            "{text}"
        );
        // Cut short: refused too.
        forged[0].data = forged_sequence_header(8192, 8192)[..4].to_vec();
        assert!(decode_av1(&forged, "cut.mp4", 4096).is_err());
        // The sequence header zeroed (an OBU of a reserved type running to the sample's end):
        // no picture; then a frame in the next sample, on which rav1d aborted: refused.
        let mut headless = encoded.clone();
        headless[0].data[header.clone()].fill(0);
        let two =
            encode_av1(&[frame.as_slice(), frame.as_slice()], 64, 48, 10, 40).expect("encode");
        let mut second = two.clone();
        let first_header = crate::media::video::obus(&second[0].data).expect("obus");
        let (_, range) = first_header
            .iter()
            .find(|(kind, _)| *kind == 1)
            .expect("header");
        second[0].data[range.clone()].fill(0);
        assert!(decode_av1(&headless, "headless.mp4", 4096).is_err());
        let error = decode_av1(&second, "headless.mp4", 4096).expect_err("refused");
        let text = format!("{error}: {:?}", std::error::Error::source(&error));
        assert!(text.contains("before any sequence header"), "{text}");
        assert!(decode_av1(&two, "two.mp4", 4096).is_ok());
    }
}
