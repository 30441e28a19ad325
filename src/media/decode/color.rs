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
}
