//! A PNG checked and inflated to its filtered rows, without the png crate: validate's full pass
//! over PNG frames. Everything that can make a PNG undecodable is checked here (the signature,
//! the header, every chunk's CRC, the zlib stream and its Adler-32, the rows' length and filter
//! types); undoing the filters, which cannot fail, is left to [`unfilter`] for the frames whose
//! pixels are wanted. Rows inflate into the caller's buffer, reused frame after frame (no
//! allocation, no zeroing, no copy of the pixels).
//!
//! Only the common layout takes this path: 8- or 16-bit grey, grey-alpha, RGB or RGBA, not
//! interlaced, no chunks beyond IHDR, IDAT, IEND and ancillary ones. Anything else, or anything
//! wrong, gives `None`, and the caller asks the png crate, whose verdict and words stand.

use super::image::MAX_IMAGE_SIDE;

/// The header of a PNG whose rows [`inflate_rows`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PngRows {
    pub width: usize,
    pub height: usize,
    /// Samples per pixel (1 grey, 2 grey-alpha, 3 RGB, 4 RGBA).
    pub channels: usize,
    /// 8 or 16.
    pub bit_depth: u8,
}

impl PngRows {
    /// Bytes per pixel.
    pub fn pixel_bytes(&self) -> usize {
        self.channels * usize::from(self.bit_depth / 8)
    }

    /// Bytes of one row's pixels (without its filter byte).
    pub fn stride(&self) -> usize {
        self.width * self.pixel_bytes()
    }
}

const SIGNATURE: &[u8; 8] = b"\x89PNG\r\n\x1a\n";

/// Checks `bytes` as a PNG of `expected` (width, height) when given, and inflates its filtered
/// rows (each row's filter type, then its bytes) into `rows`, resized to exactly their length.
/// `None` when the file takes another path, has another size or is damaged: the png crate then
/// decodes it and names the problem.
pub fn inflate_rows(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
    rows: &mut Vec<u8>,
) -> Option<PngRows> {
    if bytes.get(..8)? != SIGNATURE {
        return None;
    }
    let mut at = 8;
    let mut header: Option<PngRows> = None;
    let mut inflater = fdeflate::Decompressor::new();
    let mut written = 0;
    // Before, in and after the IDAT chunks (which must follow one another).
    let (mut in_data, mut after_data) = (false, false);
    loop {
        let length = u32::from_be_bytes(bytes.get(at..at + 4)?.try_into().ok()?) as usize;
        let kind: [u8; 4] = bytes.get(at + 4..at + 8)?.try_into().ok()?;
        let end = (at + 8).checked_add(length)?;
        let data = bytes.get(at + 8..end)?;
        let stored = u32::from_be_bytes(bytes.get(end..end + 4)?.try_into().ok()?);
        if crc32fast::hash(&bytes[at + 4..end]) != stored {
            return None;
        }
        at = end + 4;
        match (&kind, header) {
            (b"IHDR", None) => {
                let parsed = parse_header(data)?;
                if expected.is_some_and(|size| size != (parsed.width, parsed.height)) {
                    return None;
                }
                let size = parsed.height.checked_mul(parsed.stride().checked_add(1)?)?;
                // Deflate expands at most 1,032 times: a header claiming more rows than the
                // file can hold is not allocated for.
                if size / 1032 > bytes.len() {
                    return None;
                }
                rows.resize(size, 0);
                header = Some(parsed);
            }
            (_, None) => return None,
            (b"IDAT", Some(_)) if !after_data => {
                in_data = true;
                let mut input = data;
                while !input.is_empty() {
                    let (read, out) = inflater.read(input, rows, written, false).ok()?;
                    written += out;
                    input = &input[read..];
                    if (read == 0 && out == 0) || (inflater.is_done() && !input.is_empty()) {
                        return None;
                    }
                }
            }
            (b"IEND", Some(_)) => break,
            // Ancillary chunks are skipped; critical ones (PLTE, unknown) are the png crate's.
            (_, Some(_)) if kind[0].is_ascii_lowercase() => after_data |= in_data,
            _ => return None,
        }
    }
    let header = header?;
    if !inflater.is_done() {
        let (_, out) = inflater.read(&[], rows, written, true).ok()?;
        written += out;
    }
    // The stream must end exactly where the rows do, and each row's filter type be one of five.
    (inflater.is_done() && written == rows.len()).then_some(())?;
    rows.chunks_exact(header.stride() + 1)
        .all(|row| row[0] <= 4)
        .then_some(header)
}

/// The IHDR chunk's fields, when this path takes them.
fn parse_header(data: &[u8]) -> Option<PngRows> {
    if data.len() != 13 {
        return None;
    }
    let width = u32::from_be_bytes(data[0..4].try_into().ok()?);
    let height = u32::from_be_bytes(data[4..8].try_into().ok()?);
    let (bit_depth, colour, compression, filter, interlace) =
        (data[8], data[9], data[10], data[11], data[12]);
    let channels = match colour {
        0 => 1,
        2 => 3,
        4 => 2,
        6 => 4,
        _ => return None,
    };
    let sizes_ok = (1..=MAX_IMAGE_SIDE).contains(&width) && (1..=MAX_IMAGE_SIDE).contains(&height);
    let plain = compression == 0 && filter == 0 && interlace == 0;
    (sizes_ok && plain && matches!(bit_depth, 8 | 16)).then_some(PngRows {
        width: width as usize,
        height: height as usize,
        channels,
        bit_depth,
    })
}

/// Undoes the filters of `rows` (as [`inflate_rows`] left them) into `pixels`: row-major
/// samples as stored (16-bit ones big-endian).
pub fn unfilter(header: &PngRows, rows: &[u8], pixels: &mut Vec<u8>) {
    let (stride, bpp) = (header.stride(), header.pixel_bytes());
    pixels.clear();
    pixels.reserve(stride * header.height);
    for (y, row) in rows
        .chunks_exact(stride + 1)
        .take(header.height)
        .enumerate()
    {
        pixels.extend_from_slice(&row[1..]);
        let (above, current) = pixels.split_at_mut(y * stride);
        match above.len().checked_sub(stride) {
            Some(start) => unfilter_row(row[0], bpp, &above[start..], current),
            None => unfilter_first_row(row[0], bpp, current),
        }
    }
}

/// The first row's filter undone: the row above is zeros (Up adds nothing, Paeth is Sub).
fn unfilter_first_row(filter: u8, bpp: usize, current: &mut [u8]) {
    match filter {
        1 | 4 => {
            for i in bpp..current.len() {
                current[i] = current[i].wrapping_add(current[i - bpp]);
            }
        }
        3 => {
            for i in bpp..current.len() {
                current[i] = current[i].wrapping_add(current[i - bpp] / 2);
            }
        }
        _ => {}
    }
}

/// One row's filter undone in place over the row above.
fn unfilter_row(filter: u8, bpp: usize, previous: &[u8], current: &mut [u8]) {
    match (filter, bpp) {
        (1, _) => {
            for i in bpp..current.len() {
                current[i] = current[i].wrapping_add(current[i - bpp]);
            }
        }
        (2, _) => {
            for (c, p) in current.iter_mut().zip(previous) {
                *c = c.wrapping_add(*p);
            }
        }
        (3, _) => {
            for i in 0..current.len() {
                let left = if i >= bpp { current[i - bpp] } else { 0 };
                let mean = ((u16::from(left) + u16::from(previous[i])) / 2) as u8;
                current[i] = current[i].wrapping_add(mean);
            }
        }
        (4, 3) => paeth_row::<3>(previous, current),
        (4, 4) => paeth_row::<4>(previous, current),
        (4, _) => {
            for i in 0..current.len() {
                let (left, upper_left) = if i >= bpp {
                    (current[i - bpp], previous[i - bpp])
                } else {
                    (0, 0)
                };
                current[i] = current[i].wrapping_add(paeth(left, previous[i], upper_left));
            }
        }
        _ => {}
    }
}

/// Paeth undone over a row of `BPP`-byte pixels, the pixel to the left carried along.
fn paeth_row<const BPP: usize>(previous: &[u8], current: &mut [u8]) {
    let (mut left, mut upper_left) = ([0u8; BPP], [0u8; BPP]);
    for (pixel, above) in current
        .chunks_exact_mut(BPP)
        .zip(previous.chunks_exact(BPP))
    {
        for k in 0..BPP {
            pixel[k] = pixel[k].wrapping_add(paeth(left[k], above[k], upper_left[k]));
        }
        left.copy_from_slice(pixel);
        upper_left.copy_from_slice(above);
    }
}

/// The Paeth predictor (stb_image's branch-free form): of left `a`, above `b` and upper left
/// `c`, the one nearest `a + b - c`, ties to `a`, then `b`.
fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let (a, b, c) = (i16::from(a), i16::from(b), i16::from(c));
    let threshold = c * 3 - (a + b);
    let (low, high) = (a.min(b), a.max(b));
    let t0 = if high <= threshold { low } else { c };
    (if threshold <= low { high } else { t0 }) as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::image::{PngLevel, decode_png, decode_png16, encode_png, encode_png16};
    use crate::rng::SplitMix64;

    /// Every filter type (the png crate's adaptive and fixed filters), bit depth and channel
    /// count: the same pixels as the png crate.
    #[test]
    fn rows_unfilter_to_the_png_crates_pixels() {
        let mut rng = SplitMix64::new(42);
        let (mut rows, mut pixels) = (Vec::new(), Vec::new());
        for channels in [1, 3, 4] {
            for level in [PngLevel::Fast, PngLevel::Best] {
                let (w, h) = (13 + channels, 9);
                // Smooth ramps with noise: every filter wins somewhere.
                let image: Vec<u8> = (0..w * h * channels)
                    .map(|i| {
                        ((i % (w * channels)) * 3 + i / (w * channels) * 7) as u8
                            ^ (rng.next_u64() % 4) as u8
                    })
                    .collect();
                let png = encode_png(w, h, channels, &image, level).expect("encode");
                let header = inflate_rows(&png, None, &mut rows).expect("takes the fast path");
                assert_eq!(
                    (header.width, header.height, header.channels),
                    (w, h, channels)
                );
                unfilter(&header, &rows, &mut pixels);
                assert_eq!(pixels, decode_png(&png).expect("png decodes").3);
                assert_eq!(pixels, image);
            }
        }
        let values: Vec<u16> = (0..40 * 7).map(|i| (i * 233) as u16).collect();
        let png = encode_png16(40, 7, &values, PngLevel::Fast).expect("encode");
        let header = inflate_rows(&png, None, &mut rows).expect("16-bit grey");
        unfilter(&header, &rows, &mut pixels);
        let back: Vec<u16> = pixels
            .chunks_exact(2)
            .map(|p| u16::from_be_bytes([p[0], p[1]]))
            .collect();
        assert_eq!(back, decode_png16(&png).expect("decodes").2);
    }

    /// Each filter type by hand, against the png crate's decoder.
    #[test]
    fn each_filter_type_undoes_as_the_png_crate_does() {
        let mut rng = SplitMix64::new(7);
        for filter in [
            png::Filter::NoFilter,
            png::Filter::Sub,
            png::Filter::Up,
            png::Filter::Avg,
            png::Filter::Paeth,
        ] {
            let (w, h) = (11, 6);
            let image: Vec<u8> = (0..w * h * 3).map(|_| rng.next_u64() as u8).collect();
            let mut png_bytes = Vec::new();
            {
                let mut encoder = png::Encoder::new(&mut png_bytes, w as u32, h as u32);
                encoder.set_color(png::ColorType::Rgb);
                encoder.set_filter(filter);
                let mut writer = encoder.write_header().expect("header");
                writer.write_image_data(&image).expect("data");
            }
            let (mut rows, mut pixels) = (Vec::new(), Vec::new());
            let header = inflate_rows(&png_bytes, None, &mut rows).expect("fast path");
            unfilter(&header, &rows, &mut pixels);
            assert_eq!(pixels, image, "{filter:?}");
        }
    }

    /// Damage anywhere is refused (the png crate then names it); a palette image is left to
    /// the png crate.
    #[test]
    fn damaged_and_unusual_pngs_leave_the_fast_path() {
        let image: Vec<u8> = (0..16 * 8 * 3).map(|i| (i * 7) as u8).collect();
        let png = encode_png(16, 8, 3, &image, PngLevel::Fast).expect("encode");
        let mut rows = Vec::new();
        assert!(inflate_rows(&png, None, &mut rows).is_some());
        let mut rng = SplitMix64::new(3);
        for _ in 0..200 {
            let mut damaged = png.clone();
            let at = (rng.next_u64() as usize) % damaged.len();
            damaged[at] ^= 1 << (rng.next_u64() % 8);
            // One flipped bit: either refused here, or (a bit in an ignored place) the same
            // pixels the png crate finds.
            if let Some(header) = inflate_rows(&damaged, None, &mut rows) {
                let mut pixels = Vec::new();
                unfilter(&header, &rows, &mut pixels);
                assert_eq!(
                    Some(pixels),
                    decode_png(&damaged).ok().map(|d| d.3),
                    "bit at {at}"
                );
            }
        }
        for cut in [0, 8, 20, png.len() / 2, png.len() - 12, png.len() - 1] {
            assert!(
                inflate_rows(&png[..cut], None, &mut rows).is_none(),
                "cut at {cut}"
            );
        }
        let mut palette = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut palette, 2, 2);
            encoder.set_color(png::ColorType::Indexed);
            encoder.set_palette(vec![0u8, 0, 0, 255, 255, 255]);
            let mut writer = encoder.write_header().expect("header");
            writer.write_image_data(&[0, 1, 1, 0]).expect("data");
        }
        assert!(inflate_rows(&palette, None, &mut rows).is_none());
    }
}
