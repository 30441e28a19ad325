//! Rendered colour at the fast level (8-bit RGB and RGBA, the Paeth filter on every row, the
//! fdeflate stream): the very bytes the `png` crate writes with those settings (tested). A
//! 224 x 224 frame takes about 111 us here, 128 us through fdeflate's own writer and 140 us
//! through the `png` crate (BENCHMARKS.md, issue 27).
//!
//! The stream is fdeflate's: one dynamic Huffman block whose code (fixed, tuned for filtered
//! image data) sits in a constant header, every byte a literal except runs of zeros across the
//! eight-byte words of a row, which become a zero and a back-reference of distance 1. What
//! differs is how the bits are written: two bytes' codes are looked up at once
//! ([`pair_codes`]), a run's codes too ([`run_codes`]), and the bit buffer is stored eight
//! bytes at a time without a branch on its fill, where fdeflate branches on every symbol and
//! writes through `io::Write`.

use super::pixels::PngPixels;
use std::sync::OnceLock;

/// `png`'s largest IDAT chunk.
const MAX_IDAT_BYTES: usize = (u32::MAX >> 1) as usize;

/// The zlib header and the dynamic block's header (fdeflate's code table), the last byte's
/// five low bits included.
const HEADER: [u8; 54] = [
    120, 1, 237, 192, 3, 160, 36, 89, 150, 198, 241, 255, 119, 238, 141, 200, 204, 167, 114, 75,
    99, 174, 109, 219, 182, 109, 219, 182, 109, 219, 182, 109, 105, 140, 158, 150, 74, 175, 158,
    50, 51, 34, 238, 249, 118, 183, 106, 122, 166, 135, 59, 107, 213, 15,
];
const HEADER_LAST_BITS: u32 = 5;

/// Code lengths of the literal/length alphabet the header describes (fdeflate's).
const LENGTHS: [u8; 286] = [
    2, 3, 4, 5, 5, 6, 6, 7, 7, 7, 8, 8, 8, 8, 8, 9, 9, 9, 9, 9, 9, 9, 10, 10, 10, 10, 10, 10, 10,
    10, 10, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 11, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 11, 11, 11, 11, 11, 11, 11,
    11, 11, 11, 10, 11, 10, 10, 10, 10, 10, 10, 10, 10, 10, 9, 9, 9, 9, 9, 8, 9, 8, 8, 8, 8, 8, 7,
    7, 7, 6, 6, 6, 5, 4, 3, 12, 12, 12, 9, 9, 11, 10, 11, 11, 10, 11, 11, 11, 11, 11, 11, 12, 11,
    12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 12, 9,
];

/// The alphabet's codes, bit-reversed (deflate writes them from the most significant bit, the
/// bit buffer from the least): the canonical code of [`LENGTHS`].
const CODES: [u16; 286] = canonical_codes(&LENGTHS);

/// Symbols past the literals.
const END_OF_BLOCK: usize = 256;
const LENGTH_258: usize = 285;
/// First length of each length symbol 257..=284 and its extra bits (deflate's table).
const LENGTH_BASE: [u16; 28] = [
    3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131,
    163, 195, 227,
];
const LENGTH_EXTRA_BITS: [u8; 28] = [
    0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5,
];

/// Deflate's canonical Huffman code of `lengths`, each code bit-reversed in its length.
const fn canonical_codes(lengths: &[u8; 286]) -> [u16; 286] {
    let mut codes = [0u16; 286];
    let mut code = 0u32;
    let mut length = 1;
    while length <= 15 {
        let mut symbol = 0;
        while symbol < lengths.len() {
            if lengths[symbol] == length {
                codes[symbol] = ((code as u16).reverse_bits()) >> (16 - length as u32);
                code += 1;
            }
            symbol += 1;
        }
        code <<= 1;
        length += 1;
    }
    codes
}

/// The codes of two literal bytes (first byte in the low half of the index) written one after
/// the other: the bits in the low 24 bits, their count in the high 8 (at most 12 + 12).
fn pair_codes() -> &'static [u32] {
    static PAIR_CODES: OnceLock<Box<[u32]>> = OnceLock::new();
    PAIR_CODES.get_or_init(|| {
        (0..=u16::MAX)
            .map(|pair| {
                let (first, second) = (usize::from(pair & 0xff), usize::from(pair >> 8));
                let first_bits = u32::from(LENGTHS[first]);
                let bits = u32::from(CODES[first]) | u32::from(CODES[second]) << first_bits;
                bits | (first_bits + u32::from(LENGTHS[second])) << 24
            })
            .collect()
    })
}

/// The codes of a run of zero bytes, by its length (1..=258; index 0 empty): bits in the low
/// 24, their count in the high 8. As fdeflate writes them: a literal zero, then for the rest,
/// when more than four remain, a copy of the byte before (a length symbol, its extra bits, and
/// distance 1: the distance code's one bit 0), literal zeros otherwise. Longer runs put
/// length-258 copies between the zero and the rest.
fn run_codes() -> &'static [u32] {
    static RUN_CODES: OnceLock<Box<[u32]>> = OnceLock::new();
    RUN_CODES.get_or_init(|| {
        let zero = (u32::from(CODES[0]), u32::from(LENGTHS[0]));
        (0..=258u32)
            .map(|run| {
                let rest = run.saturating_sub(1);
                let (bits, count) = if run == 0 {
                    (0, 0)
                } else if rest > 4 {
                    let index = LENGTH_BASE.partition_point(|&base| u32::from(base) <= rest) - 1;
                    let symbol = 257 + index;
                    let length = u32::from(LENGTHS[symbol]);
                    let extra = rest - u32::from(LENGTH_BASE[index]);
                    (
                        u32::from(CODES[symbol]) | extra << length,
                        length + u32::from(LENGTH_EXTRA_BITS[index]) + 1,
                    )
                } else {
                    // The zero's code is all zero bits.
                    (0, rest * zero.1)
                };
                (zero.0 | bits << zero.1) | (zero.1 + count) << 24
            })
            .collect()
    })
}

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
    // The filtered rows in one IDAT chunk (`png` splits larger streams: left to it).
    let filtered_bytes = (row + 1).checked_mul(height)?;
    if filtered_bytes >= MAX_IDAT_BYTES / 2 {
        return None;
    }
    let (w, h) = (u32::try_from(width).ok()?, u32::try_from(height).ok()?);
    let start = out.len();
    out.extend_from_slice(&[137, 80, 78, 71, 13, 10, 26, 10]);
    let mut header = [0u8; 13];
    header[..4].copy_from_slice(&w.to_be_bytes());
    header[4..8].copy_from_slice(&h.to_be_bytes());
    header[8] = 8;
    header[9] = colour_type;
    chunk(out, b"IHDR", &header);
    // IDAT: its length is patched once the stream is written.
    let idat = out.len();
    out.extend_from_slice(&[0, 0, 0, 0]);
    out.extend_from_slice(b"IDAT");
    deflate_rows(out, pixels, row, bpp);
    let zlib_bytes = out.len() - idat - 8;
    if zlib_bytes > fdeflate::StoredOnlyCompressor::<()>::compressed_size(filtered_bytes) {
        out.truncate(start);
        return None;
    }
    out[idat..idat + 4].copy_from_slice(&(zlib_bytes as u32).to_be_bytes());
    let crc = crc32fast::hash(&out[idat + 4..]);
    out.extend_from_slice(&crc.to_be_bytes());
    chunk(out, b"IEND", &[]);
    Some(Ok(()))
}

/// Appends the zlib stream of the rows, each Paeth-filtered behind its filter byte (4) and
/// compressed as one call to fdeflate's `write_data`, as `png` makes it.
fn deflate_rows(out: &mut Vec<u8>, pixels: &[u8], row: usize, bpp: usize) {
    let (pairs, runs) = (pair_codes(), run_codes());
    out.extend_from_slice(&HEADER[..HEADER.len() - 1]);
    let mut pending = Pending {
        at: out.len(),
        bits: u64::from(HEADER[HEADER.len() - 1]),
        count: HEADER_LAST_BITS,
    };
    let mut checksum = simd_adler32::Adler32::new();
    let mut filtered = vec![0u8; row + 1];
    filtered[0] = 4;
    let zeros = vec![0u8; row];
    let mut previous = zeros.as_slice();
    for line in pixels.chunks_exact(row) {
        paeth(line, previous, bpp, &mut filtered[1..]);
        checksum.write(&filtered);
        pending = BitWriter::with_room(out, pending, filtered.len()).row(&filtered, pairs, runs);
        previous = line;
    }
    pending = BitWriter::with_room(out, pending, 2).end();
    out.truncate(pending.at);
    out.extend_from_slice(&checksum.finish().to_be_bytes());
}

/// The state of the bit stream between rows: `count` (< 8) bits not yet written, at `at`.
#[derive(Clone, Copy, Debug)]
struct Pending {
    at: usize,
    bits: u64,
    count: u32,
}

/// Deflate's bit order into a slice that runs past `at`, the first byte not final, by at least
/// the room [`BitWriter::with_room`] asked for. A local value (taken and given back as
/// [`Pending`]) so that its state stays in registers while bytes are stored.
struct BitWriter<'a> {
    out: &'a mut [u8],
    state: Pending,
}

impl<'a> BitWriter<'a> {
    /// Grows `out` for the codes of `bytes` input bytes: at most 12 bits a byte, plus the eight
    /// bytes every store writes.
    fn with_room(out: &'a mut Vec<u8>, pending: Pending, bytes: usize) -> Self {
        let needed = pending.at + bytes * 3 / 2 + 16;
        if out.len() < needed {
            out.resize(needed + bytes, 0);
        }
        BitWriter {
            out: out.as_mut_slice(),
            state: pending,
        }
    }

    /// Adds `count` bits (the buffer must hold no more than 63 after it).
    #[inline(always)]
    fn put(&mut self, bits: u64, count: u32) {
        self.state.bits |= bits << self.state.count;
        self.state.count += count;
    }

    /// Writes the buffer's whole bytes: all eight are stored, and `at` moves past the whole ones.
    #[inline(always)]
    fn store(&mut self) {
        let whole = self.state.count / 8;
        self.out[self.state.at..self.state.at + 8].copy_from_slice(&self.state.bits.to_le_bytes());
        self.state.at += whole as usize;
        // `whole` <= 7: no caller fills the buffer to 64 bits.
        self.state.bits >>= whole * 8;
        self.state.count -= whole * 8;
    }

    /// The end-of-block symbol and the zero bits that pad the last byte.
    fn end(mut self) -> Pending {
        self.put(
            u64::from(CODES[END_OF_BLOCK]),
            u32::from(LENGTHS[END_OF_BLOCK]),
        );
        self.store();
        self.put(0, (8 - self.state.count % 8) % 8);
        self.store();
        self.state
    }

    /// Literal bytes, two at a time.
    #[inline(always)]
    fn literals(&mut self, bytes: &[u8], pairs: &[u32]) {
        let mut twos = bytes.chunks_exact(2);
        for two in &mut twos {
            let pair = pairs[usize::from(two[0]) | usize::from(two[1]) << 8];
            self.put(u64::from(pair & 0x00ff_ffff), pair >> 24);
            self.store();
        }
        for &byte in twos.remainder() {
            self.put(
                u64::from(CODES[usize::from(byte)]),
                u32::from(LENGTHS[usize::from(byte)]),
            );
            self.store();
        }
    }

    /// Eight literal bytes (the word's lowest first): two stores of up to 48 bits.
    #[inline(always)]
    fn eight(&mut self, word: u64, pairs: &[u32]) {
        let p0 = pairs[(word & 0xffff) as usize];
        let p1 = pairs[(word >> 16 & 0xffff) as usize];
        let p2 = pairs[(word >> 32 & 0xffff) as usize];
        let p3 = pairs[(word >> 48) as usize];
        let (n0, n2) = (p0 >> 24, p2 >> 24);
        self.put(
            u64::from(p0 & 0x00ff_ffff) | u64::from(p1 & 0x00ff_ffff) << n0,
            n0 + (p1 >> 24),
        );
        self.store();
        self.put(
            u64::from(p2 & 0x00ff_ffff) | u64::from(p3 & 0x00ff_ffff) << n2,
            n2 + (p3 >> 24),
        );
        self.store();
    }

    /// `run` zero bytes as fdeflate writes them (see [`run_codes`]).
    #[inline(always)]
    fn run(&mut self, run: u32, runs: &[u32]) {
        let mut rest = run - 1;
        if rest >= 258 {
            self.put(u64::from(CODES[0]), u32::from(LENGTHS[0]));
            while rest >= 258 {
                self.put(
                    u64::from(CODES[LENGTH_258]),
                    u32::from(LENGTHS[LENGTH_258]) + 1,
                );
                self.store();
                rest -= 258;
            }
            let code = runs[rest as usize + 1];
            self.put(
                u64::from(code & 0x00ff_ffff) >> LENGTHS[0],
                (code >> 24) - u32::from(LENGTHS[0]),
            );
        } else {
            let code = runs[run as usize];
            self.put(u64::from(code & 0x00ff_ffff), code >> 24);
        }
        self.store();
    }

    /// One call of fdeflate's `write_data`: its eight-byte words in order, a run of zeros
    /// carried from a word's high bytes into the next words (never from the call before), and
    /// the bytes past the last whole word as literals after any pending run.
    fn row(mut self, data: &[u8], pairs: &[u32], runs: &[u32]) -> Pending {
        let mut run = 0u32;
        let mut words = data.chunks_exact(8);
        for bytes in &mut words {
            let mut word = [0u8; 8];
            word.copy_from_slice(bytes);
            let word = u64::from_le_bytes(word);
            if word == 0 {
                run += 8;
                continue;
            }
            if run > 0 {
                let leading = word.trailing_zeros() / 8;
                self.run(run + leading, runs);
                run = 0;
                if leading > 0 {
                    run = word.leading_zeros() / 8;
                    self.literals(&bytes[leading as usize..8 - run as usize], pairs);
                    continue;
                }
            }
            let trailing = word.leading_zeros() / 8;
            if trailing > 0 {
                self.literals(&bytes[..8 - trailing as usize], pairs);
                run = trailing;
                continue;
            }
            self.eight(word, pairs);
        }
        if run > 0 {
            self.run(run, runs);
        }
        self.literals(words.remainder(), pairs);
        self.state
    }
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
        // Stepping aside leaves what `out` held as it was.
        let mut held = vec![1u8, 2, 3];
        assert!(super::encode(&mut held, 32, 32, PngPixels::Rgb8, &random).is_none());
        assert_eq!(held, [1, 2, 3]);
    }

    #[test]
    fn zero_runs_of_every_length_and_place_match_the_png_crate() {
        // Seeded: flat stretches of random length (zero runs once filtered, from a byte to
        // several rows, across words and rows), single changes and noise, on row lengths of
        // every remainder modulo eight.
        let mut state = 11u64;
        let mut next = move |below: u64| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) % below
        };
        let mut fast_rounds = 0;
        for round in 0..24 {
            let (layout, bpp) = if round % 3 == 0 {
                (PngPixels::Rgba8, 4)
            } else {
                (PngPixels::Rgb8, 3)
            };
            let width = 1 + next(700) as usize;
            let height = 1 + next(12) as usize;
            let mut pixels = Vec::with_capacity(width * height * bpp);
            while pixels.len() < width * height * bpp {
                let longest = if next(4) == 0 { 3_000 } else { 40 };
                let stretch = 1 + next(longest) as usize;
                let value = next(256) as u8;
                let noisy = next(3) == 0;
                for _ in 0..stretch {
                    pixels.push(if noisy { next(256) as u8 } else { value });
                }
            }
            pixels.truncate(width * height * bpp);
            let expected = by_png(width, height, layout, &pixels);
            let mut ours = Vec::new();
            if super::encode(&mut ours, width, height, layout, &pixels).is_some() {
                assert_eq!(ours, expected, "round {round}: {width}x{height}");
                fast_rounds += 1;
            } else {
                // Only what `png` stores uncompressed is left to it.
                assert!(expected.len() > width * height * bpp, "round {round}");
            }
        }
        assert!(
            fast_rounds >= 20,
            "{fast_rounds} of 24 rounds took the fast path"
        );
    }
}
