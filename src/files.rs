//! The lowest level of bytes on disk, shared by the renderer and the formats: PNG encoding
//! ([`encode_png`], every colour type surgvla writes) and atomic file writes
//! ([`write_atomically`]: a temporary `.name.partial` beside the file, renamed when complete,
//! so a crash never leaves a truncated file under its final name). Imports nothing of the
//! crate.

use std::path::{Path, PathBuf};

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

/// Encodes row-major `pixels` of `layout` as PNG; the sample count must fit the size.
pub fn encode_png(
    width: usize,
    height: usize,
    layout: PngPixels,
    pixels: &[u8],
    level: PngLevel,
) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::with_capacity(pixels.len() / 2);
    encode_png_into(&mut out, width, height, layout, pixels, level)?;
    Ok(out)
}

/// [`encode_png`] appending to `out`.
pub fn encode_png_into(
    out: &mut Vec<u8>,
    width: usize,
    height: usize,
    layout: PngPixels,
    pixels: &[u8],
    level: PngLevel,
) -> Result<(), png::EncodingError> {
    if level == PngLevel::Fast
        && let Some(written) = fast_png::encode(out, width, height, layout, pixels)
    {
        return written;
    }
    let (colour, depth) = match layout {
        PngPixels::Grey8 => (png::ColorType::Grayscale, png::BitDepth::Eight),
        PngPixels::Rgb8 => (png::ColorType::Rgb, png::BitDepth::Eight),
        PngPixels::Rgba8 => (png::ColorType::Rgba, png::BitDepth::Eight),
        PngPixels::Grey16 => (png::ColorType::Grayscale, png::BitDepth::Sixteen),
    };
    let mut encoder = png::Encoder::new(out, width as u32, height as u32);
    encoder.set_color(colour);
    encoder.set_depth(depth);
    encoder.set_compression(match level {
        PngLevel::Fast => png::Compression::Fast,
        PngLevel::Default => png::Compression::Balanced,
        PngLevel::Best => png::Compression::High,
    });
    if level == PngLevel::Fast && matches!(layout, PngPixels::Rgb8 | PngPixels::Rgba8) {
        // Rendered colour: the Paeth filter on every row gives the adaptive choice's size
        // (34.9 kB a 224 x 224 frame either way) in 15 % less time (BENCHMARKS.md, issue 27).
        encoder.set_filter(png::Filter::Paeth);
    }
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()
}

/// Rendered colour at the fast level (8-bit RGB and RGBA, the Paeth filter on every row,
/// fdeflate): the very bytes the `png` crate writes with those settings (tested), without
/// going through its row buffers and a `Cursor` for every eight bytes of deflate output, which
/// took a third of the encoding's time.
mod fast_png {
    use super::PngPixels;

    /// `png`'s largest IDAT chunk.
    const MAX_IDAT_BYTES: usize = (u32::MAX >> 1) as usize;

    /// Appends the PNG to `out`; `None` when this path does not apply (another layout, a size
    /// that does not fit, or data that the `png` crate would store uncompressed).
    pub(super) fn encode(
        out: &mut Vec<u8>,
        width: usize,
        height: usize,
        layout: PngPixels,
        pixels: &[u8],
    ) -> Option<Result<(), png::EncodingError>> {
        let (colour_type, bpp) = match layout {
            PngPixels::Rgb8 => (2u8, 3),
            PngPixels::Rgba8 => (6u8, 4),
            _ => return None,
        };
        let row = width.checked_mul(bpp)?;
        if width == 0 || height == 0 || row.checked_mul(height)? != pixels.len() {
            return None;
        }
        let (w, h) = (u32::try_from(width).ok()?, u32::try_from(height).ok()?);
        let zlib = match deflate_rows(pixels, row, bpp) {
            Ok(zlib) => zlib,
            Err(error) => return Some(Err(error.into())),
        };
        if zlib.len() > fdeflate::StoredOnlyCompressor::<()>::compressed_size((row + 1) * height) {
            return None;
        }
        out.reserve(8 + 25 + zlib.len() + 12 * (zlib.len() / MAX_IDAT_BYTES + 1) + 12);
        out.extend_from_slice(&[137, 80, 78, 71, 13, 10, 26, 10]);
        let mut header = [0u8; 13];
        header[..4].copy_from_slice(&w.to_be_bytes());
        header[4..8].copy_from_slice(&h.to_be_bytes());
        header[8] = 8;
        header[9] = colour_type;
        chunk(out, b"IHDR", &header);
        for part in zlib.chunks(MAX_IDAT_BYTES) {
            chunk(out, b"IDAT", part);
        }
        chunk(out, b"IEND", &[]);
        Some(Ok(()))
    }

    /// The zlib stream of the rows, each Paeth-filtered behind its filter byte (4) and handed to
    /// the compressor as one call, as `png` does.
    fn deflate_rows(pixels: &[u8], row: usize, bpp: usize) -> std::io::Result<Vec<u8>> {
        let mut compressor = fdeflate::Compressor::new(Vec::with_capacity(pixels.len() / 4))?;
        let mut filtered = vec![0u8; row + 1];
        filtered[0] = 4;
        let zeros = vec![0u8; row];
        let mut previous = zeros.as_slice();
        for line in pixels.chunks_exact(row) {
            paeth(line, previous, bpp, &mut filtered[1..]);
            compressor.write_data(&filtered)?;
            previous = line;
        }
        compressor.finish()
    }

    /// PNG's Paeth filter of `line` over `previous` (the row above; zeros for the first), in
    /// chunks the compiler turns into vector instructions.
    fn paeth(line: &[u8], previous: &[u8], bpp: usize, out: &mut [u8]) {
        const CHUNK: usize = 32;
        let len = line.len();
        for i in 0..bpp.min(len) {
            // No left neighbour: the predictor is the byte above.
            out[i] = line[i].wrapping_sub(previous[i]);
        }
        if len <= bpp {
            return;
        }
        let mut outs = out[bpp..].chunks_exact_mut(CHUNK);
        let mut xs = line[bpp..].chunks_exact(CHUNK);
        let mut lefts = line[..len - bpp].chunks_exact(CHUNK);
        let mut aboves = previous[bpp..].chunks_exact(CHUNK);
        let mut corners = previous[..len - bpp].chunks_exact(CHUNK);
        for ((((out, x), a), b), c) in (&mut outs)
            .zip(&mut xs)
            .zip(&mut lefts)
            .zip(&mut aboves)
            .zip(&mut corners)
        {
            for i in 0..CHUNK {
                out[i] = x[i].wrapping_sub(predict(a[i], b[i], c[i]));
            }
        }
        for ((((out, x), a), b), c) in outs
            .into_remainder()
            .iter_mut()
            .zip(xs.remainder())
            .zip(lefts.remainder())
            .zip(aboves.remainder())
            .zip(corners.remainder())
        {
            *out = x.wrapping_sub(predict(*a, *b, *c));
        }
    }

    /// The Paeth predictor: of left `a`, above `b` and upper left `c`, the one nearest
    /// `a + b - c` (ties in that order), on bytes only (FPNGE's form: `|a + b - 2c|` is
    /// `|pa - pb|` when `c` lies between `a` and `b`, and loses otherwise).
    #[inline(always)]
    fn predict(a: u8, b: u8, c: u8) -> u8 {
        let pa = b.max(c) - c.min(b);
        let pb = a.max(c) - c.min(a);
        let pc = if (a < c) == (c < b) {
            pa.max(pb) - pa.min(pb)
        } else {
            255
        };
        if pa <= pb && pa <= pc {
            a
        } else if pb <= pc {
            b
        } else {
            c
        }
    }

    /// Appends one chunk: length, type, data, CRC-32 of type and data.
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        let mut crc = crc32fast::Hasher::new();
        crc.update(kind);
        crc.update(data);
        out.extend_from_slice(&crc.finalize().to_be_bytes());
    }

    #[cfg(test)]
    mod tests {
        use super::super::{PngLevel, PngPixels};

        /// What the `png` crate writes with the fast path's settings.
        fn by_png(width: usize, height: usize, layout: PngPixels, pixels: &[u8]) -> Vec<u8> {
            let mut out = Vec::new();
            let mut encoder = png::Encoder::new(&mut out, width as u32, height as u32);
            encoder.set_color(match layout {
                PngPixels::Rgba8 => png::ColorType::Rgba,
                _ => png::ColorType::Rgb,
            });
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_compression(png::Compression::Fast);
            encoder.set_filter(png::Filter::Paeth);
            let mut writer = encoder.write_header().expect("header");
            writer.write_image_data(pixels).expect("pixels");
            writer.finish().expect("finish");
            out
        }

        #[test]
        fn the_fast_path_writes_the_png_crates_bytes() {
            // A small generator of its own: this level imports nothing of the crate.
            let mut state = 3u64;
            let mut noise = move || {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                (state >> 33) as u8
            };
            for (width, height, layout, bpp) in [
                (224, 224, PngPixels::Rgb8, 3),
                (37, 5, PngPixels::Rgb8, 3),
                (1, 1, PngPixels::Rgb8, 3),
                (64, 9, PngPixels::Rgba8, 4),
            ] {
                // Flat runs (long zero runs once filtered), gradients and noise.
                let pixels: Vec<u8> = (0..width * height * bpp)
                    .map(|i| match (i / 97) % 3 {
                        0 => 40,
                        1 => (i % 251) as u8,
                        _ => noise(),
                    })
                    .collect();
                let expected = by_png(width, height, layout, &pixels);
                let mut ours = vec![9u8];
                super::super::encode_png_into(
                    &mut ours,
                    width,
                    height,
                    layout,
                    &pixels,
                    PngLevel::Fast,
                )
                .expect("encodes");
                assert_eq!(ours[1..], expected[..], "{width}x{height}, appended");
                // The camera's size takes the fast path (tiny images are stored whole).
                if width == 224 {
                    let mut fast = Vec::new();
                    super::encode(&mut fast, width, height, layout, &pixels)
                        .expect("applies")
                        .expect("encodes");
                    assert_eq!(fast, expected);
                }
            }
            // Pure noise deflates to more than its size: `png` stores it, so this path steps
            // aside; so it does for sizes that do not fit.
            let random: Vec<u8> = (0..32 * 32 * 3).map(|_| noise()).collect();
            assert!(super::encode(&mut Vec::new(), 32, 32, PngPixels::Rgb8, &random).is_none());
            assert!(super::encode(&mut Vec::new(), 32, 31, PngPixels::Rgb8, &random).is_none());
            assert!(super::encode(&mut Vec::new(), 32, 32, PngPixels::Grey8, &random).is_none());
        }
    }
}

/// The temporary name of `path` while it is being written (`.name.partial`).
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.partial"))
}

/// A file write that failed, naming the file (not its temporary name).
#[derive(Debug, thiserror::Error)]
#[error("writing {path}")]
pub struct WriteError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// Writes `bytes` to `path` through a temporary name and a rename, in a folder that exists;
/// returns the size. On failure the temporary file is removed.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<u64, WriteError> {
    let temporary = temporary_name(path);
    std::fs::write(&temporary, bytes)
        .and_then(|()| std::fs::rename(&temporary, path))
        .map_err(|source| {
            let _ = std::fs::remove_file(&temporary);
            WriteError {
                path: path.to_path_buf(),
                source,
            }
        })?;
    Ok(bytes.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_writes_leave_the_file_or_nothing() {
        let root = std::env::temp_dir().join(format!("surgvla-files-{}", std::process::id()));
        let path = root.join("a/b.bin");
        assert!(write_atomically(&path, b"abc").is_err(), "no folder a");
        std::fs::create_dir_all(root.join("a")).unwrap();
        assert_eq!(write_atomically(&path, b"abc").unwrap(), 3);
        assert_eq!(std::fs::read(&path).unwrap(), b"abc");
        assert!(!temporary_name(&path).exists());
        let blocked = root.join("a/b.bin/c.bin");
        let error = write_atomically(&blocked, b"x").unwrap_err();
        assert_eq!(error.path, blocked);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn png_layouts_round_trip_their_size() {
        for (layout, bytes) in [
            (PngPixels::Grey8, 6),
            (PngPixels::Rgb8, 18),
            (PngPixels::Rgba8, 24),
            (PngPixels::Grey16, 12),
        ] {
            assert_eq!(layout.bytes() * 6, bytes);
            let png = encode_png(3, 2, layout, &vec![7; bytes], PngLevel::Fast).unwrap();
            assert_eq!(&png[1..4], b"PNG");
        }
        assert!(encode_png(3, 2, PngPixels::Rgb8, &[0; 5], PngLevel::Fast).is_err());
    }
}
