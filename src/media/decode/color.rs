//! The YUV -> RGB conversion a stream asks for: its matrix (BT.601, BT.709, BT.2020) and range
//! (limited or full), as the AV1 sequence header or H.264's VUI signal them (ITU-T H.273 codes),
//! BT.601 limited range when a stream says nothing, as FFmpeg assumes. Integer arithmetic in
//! 8-bit fixed point: the same bytes on every machine.

/// The matrix coefficients of a YUV stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Matrix {
    #[default]
    Bt601,
    Bt709,
    Bt2020,
}

/// How a stream's YUV samples map to RGB.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ColorSpace {
    pub matrix: Matrix,
    /// Full range (0-255) rather than limited (16-235 luma, 16-240 chroma).
    pub full_range: bool,
}

impl ColorSpace {
    /// From H.273's `matrix_coefficients` (1: BT.709; 9, 10: BT.2020; 5, 6 and unspecified:
    /// BT.601) and the full-range flag.
    pub fn from_h273(matrix_coefficients: u32, full_range: bool) -> Self {
        let matrix = match matrix_coefficients {
            1 => Matrix::Bt709,
            9 | 10 => Matrix::Bt2020,
            _ => Matrix::Bt601,
        };
        ColorSpace { matrix, full_range }
    }

    /// (luma scale, R from V, G from U, G from V, B from U), x256.
    fn coefficients(self) -> (i32, i32, i32, i32, i32) {
        match (self.matrix, self.full_range) {
            (Matrix::Bt601, false) => (298, 409, 100, 208, 516),
            (Matrix::Bt709, false) => (298, 459, 55, 136, 541),
            (Matrix::Bt2020, false) => (298, 430, 48, 167, 548),
            (Matrix::Bt601, true) => (256, 359, 88, 183, 454),
            (Matrix::Bt709, true) => (256, 403, 48, 120, 475),
            (Matrix::Bt2020, true) => (256, 377, 42, 146, 482),
        }
    }

    /// One pixel's RGB.
    pub fn rgb(self, y: u8, u: u8, v: u8) -> [u8; 3] {
        let (scale, rv, gu, gv, bu) = self.coefficients();
        let offset = if self.full_range { 0 } else { 16 };
        let c = scale * (i32::from(y) - offset) + 128;
        let d = i32::from(u) - 128;
        let e = i32::from(v) - 128;
        let clip = |value: i32| (value >> 8).clamp(0, 255) as u8;
        [
            clip(c + rv * e),
            clip(c - gu * d - gv * e),
            clip(c + bu * d),
        ]
    }
}

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

/// The colour space the first sequence parameter set in Annex B bytes signals in its VUI
/// (None: no SPS; BT.601 limited when it signals nothing).
pub fn h264_color_space(annex_b: &[u8]) -> Option<ColorSpace> {
    let mut at = 0;
    while at + 4 < annex_b.len() {
        if annex_b[at..].starts_with(&[0, 0, 1]) && annex_b[at + 3] & 0x1f == 7 {
            let end = annex_b[at + 3..]
                .windows(3)
                .position(|w| w == [0, 0, 1])
                .map_or(annex_b.len(), |p| at + 3 + p);
            return Some(sps_color(&annex_b[at + 4..end]).unwrap_or_default());
        }
        at += 1;
    }
    None
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
fn sps_color(payload: &[u8]) -> Option<ColorSpace> {
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
    bits.ue()?; // max_num_ref_frames
    bits.bit()?; // gaps
    bits.ue()?;
    bits.ue()?; // size in macroblocks
    if bits.bit()? == 0 {
        bits.bit()?; // mb_adaptive_frame_field
    }
    bits.bit()?; // direct_8x8_inference
    if bits.bit()? == 1 {
        for _ in 0..4 {
            bits.ue()?; // cropping
        }
    }
    if bits.bit()? == 0 {
        return Some(ColorSpace::default()); // no VUI
    }
    if bits.bit()? == 1 && bits.bits(8)? == 255 {
        bits.bits(32)?; // extended sample aspect ratio
    }
    if bits.bit()? == 1 {
        bits.bit()?; // overscan_appropriate
    }
    if bits.bit()? == 0 {
        return Some(ColorSpace::default()); // no video signal type
    }
    bits.bits(3)?; // video_format
    let full_range = bits.bit()? == 1;
    let matrix = if bits.bit()? == 1 {
        bits.bits(16)?; // primaries, transfer
        bits.bits(8)?
    } else {
        2
    };
    Some(ColorSpace::from_h273(matrix, full_range))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_matrix_keeps_grey_grey_and_spans_the_range() {
        for matrix in [Matrix::Bt601, Matrix::Bt709, Matrix::Bt2020] {
            let limited = ColorSpace {
                matrix,
                full_range: false,
            };
            assert_eq!(limited.rgb(16, 128, 128), [0, 0, 0]);
            assert_eq!(limited.rgb(235, 128, 128), [255, 255, 255]);
            let full = ColorSpace {
                matrix,
                full_range: true,
            };
            assert_eq!(full.rgb(0, 128, 128), [0, 0, 0]);
            assert_eq!(full.rgb(255, 128, 128), [255, 255, 255]);
            assert_eq!(full.rgb(100, 128, 128), [100, 100, 100]);
        }
        // Pure red in BT.709 limited (Y 63, U 102, V 240) comes back full red; read as BT.601
        // it would be a darker red.
        let bt709 = ColorSpace::from_h273(1, false);
        let [r, g, b] = bt709.rgb(63, 102, 240);
        assert!(r >= 253 && g <= 2 && b <= 2, "{r} {g} {b}");
        let [r601, _, _] = ColorSpace::default().rgb(63, 102, 240);
        assert!(r601 < 240, "{r601}");
    }

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
}
