//! Charts as PNG, drawn in pure Rust: a [`Canvas`] of RGB pixels with filled rectangles, lines
//! and text in an 8x8 bitmap font compiled in (`font8x8`, so no system font or library), and
//! the charts surgvla draws: success rates with their 95 % intervals, policies side by side and
//! tasks grouped by level (`eval`'s `results.png`, `surgvla report`), panels of histograms and
//! ranges (`info --plot`), both in [`plots`], and a perturbation suite's task x variant grid
//! ([`heatmap`]). Integer geometry only: the same numbers
//! give the same bytes on every machine.

pub mod heatmap;
pub mod plots;

use crate::files::{PngLevel, PngPixels, encode_png};

/// An RGB colour.
pub type Rgb = [u8; 3];

pub const WHITE: Rgb = [255, 255, 255];
pub const BLACK: Rgb = [0, 0, 0];
pub const GREY: Rgb = [200, 200, 200];
pub const DARK: Rgb = [90, 90, 90];
/// The series' colours, in turn (colour-blind safe: Okabe and Ito's palette).
pub const SERIES: [Rgb; 7] = [
    [0, 114, 178],
    [230, 159, 0],
    [0, 158, 115],
    [204, 121, 167],
    [86, 180, 233],
    [213, 94, 0],
    [240, 228, 66],
];

/// Pixels of one glyph's side at scale 1.
pub const GLYPH_PX: usize = 8;

/// An image being drawn, row-major RGB, (0, 0) at the top left.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    pub width_px: usize,
    pub height_px: usize,
    pub pixels: Vec<u8>,
}

impl Canvas {
    /// A canvas of one colour.
    pub fn new(width_px: usize, height_px: usize, background: Rgb) -> Self {
        Canvas {
            width_px,
            height_px,
            pixels: background.repeat(width_px * height_px),
        }
    }

    /// The colour at (x, y); None outside.
    pub fn at(&self, x: usize, y: usize) -> Option<Rgb> {
        if x >= self.width_px || y >= self.height_px {
            return None;
        }
        let i = (y * self.width_px + x) * 3;
        Some([self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]])
    }

    fn set(&mut self, x: usize, y: usize, colour: Rgb) {
        if x < self.width_px && y < self.height_px {
            let i = (y * self.width_px + x) * 3;
            self.pixels[i..i + 3].copy_from_slice(&colour);
        }
    }

    /// Copies an RGB image `width` pixels wide with its top left at (x0, y0), clipped to the
    /// canvas.
    pub fn paste(&mut self, x0: usize, y0: usize, width: usize, rgb: &[u8]) {
        let rows = rgb.len() / 3 / width.max(1);
        for y in 0..rows.min(self.height_px.saturating_sub(y0)) {
            let row = &rgb[y * width * 3..(y + 1) * width * 3];
            let start = ((y0 + y) * self.width_px + x0) * 3;
            let visible = width.min(self.width_px.saturating_sub(x0)) * 3;
            self.pixels[start..start + visible].copy_from_slice(&row[..visible]);
        }
    }

    /// Fills `[x0, x1) x [y0, y1)`, clipped to the canvas.
    pub fn fill(&mut self, x0: usize, y0: usize, x1: usize, y1: usize, colour: Rgb) {
        for y in y0..y1.min(self.height_px) {
            for x in x0..x1.min(self.width_px) {
                self.set(x, y, colour);
            }
        }
    }

    /// A horizontal line from `x0` to `x1` (inclusive) at `y`.
    pub fn hline(&mut self, x0: usize, x1: usize, y: usize, colour: Rgb) {
        self.fill(x0, y, x1 + 1, y + 1, colour);
    }

    /// A vertical line from `y0` to `y1` (inclusive) at `x`.
    pub fn vline(&mut self, x: usize, y0: usize, y1: usize, colour: Rgb) {
        self.fill(x, y0.min(y1), x + 1, y0.max(y1) + 1, colour);
    }

    /// The width of `text` at `scale` (each character `8 * scale` pixels).
    pub fn text_width(text: &str, scale: usize) -> usize {
        text.chars().count() * GLYPH_PX * scale
    }

    /// Draws `text` with its top left at (x, y); characters outside ASCII are drawn as '?'.
    pub fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, colour: Rgb) {
        for (k, c) in text.chars().enumerate() {
            let code = if c.is_ascii() {
                c as usize
            } else {
                '?' as usize
            };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            let left = x + k * GLYPH_PX * scale;
            for (row, bits) in glyph.iter().enumerate() {
                for column in 0..GLYPH_PX {
                    if bits & (1 << column) != 0 {
                        let (px, py) = (left + column * scale, y + row * scale);
                        self.fill(px, py, px + scale, py + scale, colour);
                    }
                }
            }
        }
    }

    /// `text` centred on `centre_x`.
    pub fn text_centred(
        &mut self,
        centre_x: usize,
        y: usize,
        text: &str,
        scale: usize,
        colour: Rgb,
    ) {
        let width = Self::text_width(text, scale);
        self.text(centre_x.saturating_sub(width / 2), y, text, scale, colour);
    }

    /// The canvas as PNG bytes.
    pub fn png(&self) -> Result<Vec<u8>, png::EncodingError> {
        encode_png(
            self.width_px,
            self.height_px,
            PngPixels::Rgb8,
            &self.pixels,
            PngLevel::Default,
        )
    }
}

/// `text` cut to at most `chars` characters (a trailing '.' marks the cut).
pub fn fit(text: &str, chars: usize) -> String {
    if text.chars().count() <= chars {
        return text.to_string();
    }
    let mut cut: String = text.chars().take(chars.saturating_sub(1)).collect();
    cut.push('.');
    cut
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_from_the_font_and_fits() {
        let mut canvas = Canvas::new(40, 10, WHITE);
        canvas.text(0, 0, "I", 1, BLACK);
        let inked = (0..8)
            .flat_map(|y| (0..8).map(move |x| (x, y)))
            .filter(|&(x, y)| canvas.at(x, y) == Some(BLACK))
            .count();
        assert!(inked > 5, "the glyph is drawn");
        assert_eq!(canvas.at(20, 5), Some(WHITE), "nothing past it");
        assert_eq!(Canvas::text_width("abc", 2), 48);
        assert_eq!(fit("pick_and_place", 6), "pick_.");
        assert_eq!(fit("T1-1", 6), "T1-1");
    }
}
