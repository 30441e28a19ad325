//! What a PNG is asked for: its compression level and its pixel layout, shared by the encoders
//! (the `png` crate and the fast path).

/// PNG compression for encoded images.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum PngLevel {
    #[default]
    Fast,
    Default,
    Best,
}

/// The pixel layouts surgvla stores as PNG.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngPixels {
    /// 8-bit grey (masks).
    Grey8,
    /// 8-bit RGB.
    Rgb8,
    /// 8-bit RGBA (another tool's images).
    Rgba8,
    /// 16-bit grey, big-endian samples as PNG stores them (RLDS depth in millimetres).
    Grey16,
}

impl PngPixels {
    /// Bytes per pixel.
    pub fn bytes(self) -> usize {
        match self {
            PngPixels::Grey8 => 1,
            PngPixels::Rgb8 => 3,
            PngPixels::Rgba8 => 4,
            PngPixels::Grey16 => 2,
        }
    }
}
