//! H.264 sequence parameter sets, read before OpenH264 sees them: the coded picture size and
//! reference frames (which the decoder allocates from), and the VUI's colour description
//! ([`super::color::ColorSpace`]). Only the fields up to the colour description are parsed.

use super::color::ColorSpace;

/// Reads H.264 bits (emulation prevention bytes removed).
struct Bits {
    bytes: Vec<u8>,
    at: usize,
}

impl Bits {
    fn new(nal_payload: &[u8]) -> Self {
        let mut bytes = Vec::with_capacity(nal_payload.len());
        let mut zeros = 0;
        for &b in nal_payload {
            if zeros >= 2 && b == 3 {
                zeros = 0;
                continue;
            }
            zeros = if b == 0 { zeros + 1 } else { 0 };
            bytes.push(b);
        }
        Bits { bytes, at: 0 }
    }

    fn bit(&mut self) -> Option<u32> {
        let byte = *self.bytes.get(self.at / 8)?;
        let bit = (byte >> (7 - self.at % 8)) & 1;
        self.at += 1;
        Some(u32::from(bit))
    }

    fn bits(&mut self, n: u32) -> Option<u32> {
        (0..n).try_fold(0, |acc, _| Some((acc << 1) | self.bit()?))
    }

    /// Unsigned Exp-Golomb.
    fn ue(&mut self) -> Option<u32> {
        let mut zeros = 0;
        while self.bit()? == 0 {
            zeros += 1;
            if zeros > 31 {
                return None;
            }
        }
        Some((1u32 << zeros) - 1 + self.bits(zeros)?)
    }

    fn se(&mut self) -> Option<i64> {
        let k = i64::from(self.ue()?);
        Some(if k % 2 == 1 { (k + 1) / 2 } else { -(k / 2) })
    }
}

/// What an SPS declares that decoding depends on.
struct Sps {
    max_ref_frames: u32,
    /// Coded size (before cropping): what the decoder allocates per picture.
    width_px: u64,
    height_px: u64,
    color: ColorSpace,
}

/// The SPS NAL units (payload after the header byte) in Annex B bytes.
fn sps_payloads(annex_b: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut at = 0;
    std::iter::from_fn(move || {
        while at + 4 < annex_b.len() {
            let start = at;
            at += 1;
            if annex_b[start..].starts_with(&[0, 0, 1]) && annex_b[start + 3] & 0x1f == 7 {
                let end = annex_b[start + 3..]
                    .windows(3)
                    .position(|w| w == [0, 0, 1])
                    .map_or(annex_b.len(), |p| start + 3 + p);
                at = end;
                return Some(&annex_b[start + 4..end]);
            }
        }
        None
    })
}

/// The colour space the first sequence parameter set in Annex B bytes signals in its VUI
/// (None: no SPS; BT.601 limited when it signals nothing).
pub(super) fn h264_color_space(annex_b: &[u8]) -> Option<ColorSpace> {
    let payload = sps_payloads(annex_b).next()?;
    Some(read_sps(payload).map(|sps| sps.color).unwrap_or_default())
}

/// Why the sequence parameter sets in `annex_b` (one sample) must not reach the decoder: one
/// cut short, declaring pictures over `max_side` on a side (the decoder allocates them, and
/// its reference frames, before checking anything), or more reference frames than the
/// standard's 16.
pub(super) fn h264_sps_problem(annex_b: &[u8], max_side: u32) -> Option<String> {
    sps_payloads(annex_b).find_map(|payload| match read_sps(payload) {
        None => Some("a sequence parameter set ends early".to_string()),
        Some(sps) if sps.width_px > u64::from(max_side) || sps.height_px > u64::from(max_side) => {
            Some(format!(
                "a sequence parameter set declares {} x {} pictures, more than {max_side} a side",
                sps.width_px, sps.height_px
            ))
        }
        Some(sps) if sps.max_ref_frames > 16 => Some(format!(
            "a sequence parameter set declares {} reference frames, more than H.264's 16",
            sps.max_ref_frames
        )),
        Some(_) => None,
    })
}

/// Skips a scaling list of `size` entries.
fn skip_scaling_list(bits: &mut Bits, size: usize) -> Option<()> {
    let (mut last, mut next) = (8i64, 8i64);
    for _ in 0..size {
        if next != 0 {
            next = (last + bits.se()? + 256) % 256;
        }
        if next != 0 {
            last = next;
        }
    }
    Some(())
}

/// Parses an SPS (after its NAL header byte) up to the VUI's colour description.
fn read_sps(payload: &[u8]) -> Option<Sps> {
    let mut bits = Bits::new(payload);
    let profile = bits.bits(8)?;
    bits.bits(16)?; // constraint flags, level
    bits.ue()?; // seq_parameter_set_id
    if [100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135].contains(&profile) {
        let chroma_format = bits.ue()?;
        if chroma_format == 3 {
            bits.bit()?;
        }
        bits.ue()?;
        bits.ue()?; // bit depths
        bits.bit()?; // qpprime_y_zero_transform_bypass
        if bits.bit()? == 1 {
            let lists = if chroma_format == 3 { 12 } else { 8 };
            for i in 0..lists {
                if bits.bit()? == 1 {
                    skip_scaling_list(&mut bits, if i < 6 { 16 } else { 64 })?;
                }
            }
        }
    }
    bits.ue()?; // log2_max_frame_num
    match bits.ue()? {
        0 => {
            bits.ue()?;
        }
        1 => {
            bits.bit()?;
            bits.se()?;
            bits.se()?;
            for _ in 0..bits.ue()?.min(255) {
                bits.se()?;
            }
        }
        _ => {}
    }
    let max_ref_frames = bits.ue()?;
    bits.bit()?; // gaps
    let width_mbs = u64::from(bits.ue()?) + 1;
    let height_map_units = u64::from(bits.ue()?) + 1;
    let frame_mbs_only = bits.bit()? == 1;
    if !frame_mbs_only {
        bits.bit()?; // mb_adaptive_frame_field
    }
    let mut sps = Sps {
        max_ref_frames,
        width_px: width_mbs * 16,
        height_px: height_map_units * 16 * if frame_mbs_only { 1 } else { 2 },
        color: ColorSpace::default(),
    };
    bits.bit()?; // direct_8x8_inference
    if bits.bit()? == 1 {
        for _ in 0..4 {
            bits.ue()?; // cropping
        }
    }
    if bits.bit()? == 0 {
        return Some(sps); // no VUI
    }
    if bits.bit()? == 1 && bits.bits(8)? == 255 {
        bits.bits(32)?; // extended sample aspect ratio
    }
    if bits.bit()? == 1 {
        bits.bit()?; // overscan_appropriate
    }
    if bits.bit()? == 0 {
        return Some(sps); // no video signal type
    }
    bits.bits(3)?; // video_format
    let full_range = bits.bit()? == 1;
    let matrix = if bits.bit()? == 1 {
        bits.bits(16)?; // primaries, transfer
        bits.bits(8)?
    } else {
        2
    };
    sps.color = ColorSpace::from_h273(matrix, full_range);
    Some(sps)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vui_of_an_sps_is_read() {
        // libx264 fixtures: untagged (BT.601 limited assumed).
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/video/x264_high_bframes.mp4");
        let mut reader = crate::media::demux::VideoReader::open(&path).expect("open");
        let span = reader.decodable(0.0, 0.05).expect("span");
        assert_eq!(
            h264_color_space(&span.samples[0].data),
            Some(ColorSpace::default())
        );
        assert_eq!(h264_color_space(&[0, 0, 0, 1, 0x65, 1, 2, 3]), None);
        // Tagged BT.709 full range (libx264 through PyAV): read from the VUI, and the frame
        // converts to what FFmpeg's swscale gives with those tags stated (PyAV's
        // to_ndarray("rgb24") alone ignores the tags and is up to 33 levels off).
        let fixture = path.with_file_name("x264_bt709_full.mp4");
        let mut reader = crate::media::demux::VideoReader::open(&fixture).expect("open");
        let span = reader.decodable(0.0, 0.05).expect("span");
        let tagged = h264_color_space(&span.samples[0].data).expect("sps");
        assert_eq!(tagged, ColorSpace::from_h273(1, true));
        let pictures =
            super::super::decode_h264(&span.samples[..1], "x264_bt709_full.mp4").expect("decode");
        assert_eq!(pictures[0].color, tagged);
        let ours = super::super::rgb_from_yuv420(&pictures[0]).expect("planes");
        let theirs = std::fs::read(fixture.with_extension("rgb")).expect("rgb");
        let worst = ours.iter().zip(&theirs).map(|(a, b)| a.abs_diff(*b)).max();
        assert!(worst <= Some(3), "{worst:?}");
    }

    /// An SPS (Baseline, no VUI) of `width_mbs` x `height_mbs` macroblocks and `refs` reference
    /// frames, as Annex B with emulation prevention.
    fn forged_sps(width_mbs: u32, height_mbs: u32, refs: u32) -> Vec<u8> {
        let mut bits: Vec<u8> = Vec::new();
        let mut push =
            |value: u32, n: u32| bits.extend((0..n).rev().map(|k| ((value >> k) & 1) as u8));
        let ue = |push: &mut dyn FnMut(u32, u32), value: u32| {
            let coded = value + 1;
            let length = 32 - coded.leading_zeros();
            push(0, length - 1);
            push(coded, length);
        };
        push(66, 8);
        push(30, 16);
        ue(&mut push, 0); // id
        ue(&mut push, 0); // log2_max_frame_num - 4
        ue(&mut push, 2); // poc type 2
        ue(&mut push, refs);
        push(0, 1);
        ue(&mut push, width_mbs - 1);
        ue(&mut push, height_mbs - 1);
        push(1, 1); // frame_mbs_only
        push(1, 1); // direct_8x8
        push(0, 1); // no cropping
        push(0, 1); // no VUI
        push(1, 1); // stop bit
        while !bits.len().is_multiple_of(8) {
            bits.push(0);
        }
        let raw: Vec<u8> = bits
            .chunks(8)
            .map(|c| c.iter().fold(0, |b, bit| (b << 1) | bit))
            .collect();
        let mut out = vec![0, 0, 0, 1, 0x67];
        let mut zeros = 0;
        for b in raw {
            if zeros >= 2 && b <= 3 {
                out.push(3);
                zeros = 0;
            }
            zeros = if b == 0 { zeros + 1 } else { 0 };
            out.push(b);
        }
        out
    }

    /// Sizes and reference counts are read from real and forged SPSs; those the decoder must
    /// not be given are refused before it sees them.
    #[test]
    fn sequence_parameter_sets_declaring_huge_pictures_are_refused() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/video/x264_high_bframes.mp4");
        let mut reader = crate::media::demux::VideoReader::open(&path).expect("open");
        let span = reader.decodable(0.0, 0.05).expect("span");
        let data = &span.samples[0].data;
        let sps = read_sps(sps_payloads(data).next().expect("sps")).expect("read");
        assert_eq!((sps.width_px, sps.height_px), (64, 48));
        assert_eq!(h264_sps_problem(data, 4096), None);
        let small = forged_sps(4, 3, 1);
        let read = read_sps(sps_payloads(&small).next().expect("sps")).expect("read");
        assert_eq!(
            (read.width_px, read.height_px, read.max_ref_frames),
            (64, 48, 1)
        );
        assert_eq!(h264_sps_problem(&small, 4096), None);
        let huge = h264_sps_problem(&forged_sps(512, 512, 1), 4096).expect("refused");
        assert!(huge.contains("8192 x 8192"), "{huge}");
        let refs = h264_sps_problem(&forged_sps(4, 3, 40), 4096).expect("refused");
        assert!(refs.contains("40 reference frames"), "{refs}");
        let cut = forged_sps(4, 3, 1);
        assert!(h264_sps_problem(&cut[..7], 4096).is_some());
    }
}
