//! One decoded picture, as every decoder hands it over.

use super::color::ColorSpace;

/// One decoded picture: 8-bit planar YUV 4:2:0, planes without padding.
#[derive(Clone, Debug, PartialEq)]
pub struct YuvFrame {
    pub width_px: u32,
    pub height_px: u32,
    /// Luma, `width_px` x `height_px`.
    pub y: Vec<u8>,
    /// Chroma, each `ceil(width_px / 2)` x `ceil(height_px / 2)`.
    pub u: Vec<u8>,
    pub v: Vec<u8>,
    /// The matrix and range the stream signals.
    pub color: ColorSpace,
}
