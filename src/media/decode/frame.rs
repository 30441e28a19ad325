//! One decoded picture, as every decoder hands it over, and the check that each sample gave one.

use super::color::ColorSpace;
use crate::media::MediaError;

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

/// `count` pictures from `samples` samples: each sample must give one picture.
pub(super) fn every_sample_decoded(
    count: usize,
    samples: usize,
    what: &str,
) -> Result<usize, MediaError> {
    if count != samples {
        return Err(MediaError::Decode {
            what: what.to_string(),
            source: format!("{samples} samples gave {count} pictures").into(),
        });
    }
    Ok(count)
}
