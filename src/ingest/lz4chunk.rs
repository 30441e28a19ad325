//! lz4-compressed MCAP chunks, decoded in pure Rust: a push decoder of the LZ4 frame format
//! ([`Lz4Chunks`], registered with the `mcap` crate's sans-io reader, whose own lz4 decoder
//! compiles C). Frames may follow each other (and skippable frames); blocks may be independent
//! or linked (each referring to the 64 KiB decoded before it); block and content checksums are
//! skipped (the chunk's CRC covers the decoded bytes).
//!
//! The bytes are untrusted: a block is at most its frame's stated maximum (4 MiB at most) and
//! decodes into a buffer of that size, never more.

use mcap::sans_io::decompressor::{DecompressResult, Decompressor};
use mcap::{McapError, McapResult};

const MAGIC: u32 = 0x184D_2204;
/// Skippable frames: magic 0x184D2A50 to 0x184D2A5F.
const SKIPPABLE: u32 = 0x184D_2A50;
/// What a linked block may refer back to.
const WINDOW: usize = 64 << 10;

/// Where the decoder is in the compressed stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Place {
    /// Before a frame's magic.
    FrameStart,
    /// Among a frame's blocks.
    Blocks {
        max_block: usize,
        linked: bool,
        block_checksum: bool,
        content_checksum: bool,
    },
}

/// The `"lz4"` chunk decompressor (see the module overview).
pub struct Lz4Chunks {
    /// Compressed bytes taken but not yet decoded.
    input: Vec<u8>,
    /// Decoded bytes not yet handed out, from `handed` on.
    output: Vec<u8>,
    handed: usize,
    /// The last [`WINDOW`] bytes decoded in the frame (linked blocks refer to them).
    window: Vec<u8>,
    place: Place,
}

impl Default for Lz4Chunks {
    fn default() -> Self {
        Lz4Chunks {
            input: Vec::new(),
            output: Vec::new(),
            handed: 0,
            window: Vec::new(),
            place: Place::FrameStart,
        }
    }
}

fn damaged(problem: &str) -> McapError {
    McapError::DecompressionError(format!("lz4: {problem}"))
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at + 4)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

impl Lz4Chunks {
    /// Decodes from `input` until some output is ready or more input is needed; returns the
    /// bytes of `input` used.
    fn step(&mut self) -> McapResult<usize> {
        let input = std::mem::take(&mut self.input);
        let mut used = 0;
        let stepped = loop {
            if self.output.len() != self.handed {
                break Ok(());
            }
            let rest = &input[used..];
            let taken = match self.place {
                Place::FrameStart => self.frame_header(rest),
                Place::Blocks { .. } => self.block(rest),
            };
            match taken {
                Ok(Some(n)) => used += n,
                Ok(None) => break Ok(()),
                Err(error) => break Err(error),
            }
        };
        self.input = input;
        stepped.map(|()| used)
    }

    /// Reads a frame header (or skips a skippable frame); None: more input needed.
    fn frame_header(&mut self, bytes: &[u8]) -> McapResult<Option<usize>> {
        let Some(magic) = u32_at(bytes, 0) else {
            return Ok(None);
        };
        if magic & 0xFFFF_FFF0 == SKIPPABLE {
            let Some(size) = u32_at(bytes, 4) else {
                return Ok(None);
            };
            let total = 8 + size as usize;
            return Ok((bytes.len() >= total).then_some(total));
        }
        if magic != MAGIC {
            return Err(damaged("not an LZ4 frame"));
        }
        let (Some(&flags), Some(&bd)) = (bytes.get(4), bytes.get(5)) else {
            return Ok(None);
        };
        if flags >> 6 != 1 {
            return Err(damaged("an LZ4 frame of another version"));
        }
        let max_block = match (bd >> 4) & 7 {
            4 => 64 << 10,
            5 => 256 << 10,
            6 => 1 << 20,
            7 => 4 << 20,
            _ => {
                return Err(damaged(
                    "a block size that is not 64 KiB, 256 KiB, 1 MiB or 4 MiB",
                ));
            }
        };
        let mut length = 7;
        if flags & 0x08 != 0 {
            length += 8;
        }
        if flags & 0x01 != 0 {
            return Err(damaged("a frame that needs a dictionary"));
        }
        if bytes.len() < length {
            return Ok(None);
        }
        self.place = Place::Blocks {
            max_block,
            linked: flags & 0x20 == 0,
            block_checksum: flags & 0x10 != 0,
            content_checksum: flags & 0x04 != 0,
        };
        self.window.clear();
        Ok(Some(length))
    }

    /// Decodes the next block (or the frame's end); None: more input needed.
    fn block(&mut self, bytes: &[u8]) -> McapResult<Option<usize>> {
        let Place::Blocks {
            max_block,
            linked,
            block_checksum,
            content_checksum,
        } = self.place
        else {
            return Ok(None);
        };
        let Some(word) = u32_at(bytes, 0) else {
            return Ok(None);
        };
        if word == 0 {
            let length = 4 + if content_checksum { 4 } else { 0 };
            if bytes.len() < length {
                return Ok(None);
            }
            self.place = Place::FrameStart;
            return Ok(Some(length));
        }
        let size = (word & 0x7FFF_FFFF) as usize;
        if size > max_block {
            return Err(damaged("a block larger than its frame allows"));
        }
        let length = 4 + size + if block_checksum { 4 } else { 0 };
        if bytes.len() < length {
            return Ok(None);
        }
        let data = &bytes[4..4 + size];
        self.output.clear();
        self.handed = 0;
        if word & 0x8000_0000 != 0 {
            self.output.extend_from_slice(data);
        } else {
            self.output.resize(max_block, 0);
            let written = if linked {
                lz4_flex::block::decompress_into_with_dict(data, &mut self.output, &self.window)
            } else {
                lz4_flex::block::decompress_into(data, &mut self.output)
            }
            .map_err(|e| damaged(&format!("a block that does not decode: {e}")))?;
            self.output.truncate(written);
        }
        if linked {
            self.window.extend_from_slice(&self.output);
            let excess = self.window.len().saturating_sub(WINDOW);
            self.window.drain(..excess);
        }
        Ok(Some(length))
    }
}

impl Decompressor for Lz4Chunks {
    fn next_read_size(&self) -> usize {
        0
    }

    fn decompress(&mut self, src: &[u8], dst: &mut [u8]) -> McapResult<DecompressResult> {
        let consumed = if self.output.len() == self.handed {
            self.input.extend_from_slice(src);
            let used = self.step()?;
            self.input.drain(..used);
            src.len()
        } else {
            0
        };
        let ready = &self.output[self.handed..];
        let wrote = ready.len().min(dst.len());
        dst[..wrote].copy_from_slice(&ready[..wrote]);
        self.handed += wrote;
        Ok(DecompressResult { consumed, wrote })
    }

    fn reset(&mut self) -> McapResult<()> {
        *self = Lz4Chunks::default();
        Ok(())
    }

    fn name(&self) -> &'static str {
        "lz4"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Decodes `compressed` through the push interface in pieces of `piece` bytes, asking for
    /// at most `out` bytes a call.
    fn push(compressed: &[u8], expected_len: usize, piece: usize, out: usize) -> Vec<u8> {
        let mut decoder = Lz4Chunks::default();
        let mut decoded = Vec::new();
        let mut at = 0;
        let mut idle = 0;
        while decoded.len() < expected_len {
            let end = (at + piece).min(compressed.len());
            let mut buffer = vec![0u8; out];
            let result = decoder
                .decompress(&compressed[at..end], &mut buffer)
                .expect("decode");
            at += result.consumed;
            decoded.extend_from_slice(&buffer[..result.wrote]);
            idle = if result.consumed + result.wrote == 0 {
                idle + 1
            } else {
                0
            };
            assert!(idle < 3, "no progress at {at} of {}", compressed.len());
        }
        decoded
    }

    fn sample() -> Vec<u8> {
        (0..300_000u32)
            .flat_map(|i| [(i % 251) as u8, (i / 977) as u8, b'x'])
            .collect()
    }

    #[test]
    fn frames_of_lz4_flex_decode_in_any_pieces() {
        let data = sample();
        let mut encoder = lz4_flex::frame::FrameEncoder::new(Vec::new());
        std::io::Write::write_all(&mut encoder, &data).expect("compress");
        let compressed = encoder.finish().expect("finish");
        for (piece, out) in [(usize::MAX / 2, 1 << 20), (7, 1), (4096, 333)] {
            assert_eq!(push(&compressed, data.len(), piece, out), data);
        }
    }

    #[test]
    fn linked_blocks_and_uncompressed_blocks_decode() {
        // A frame by hand: 64 KiB blocks, linked; the second block refers into the first.
        let first: Vec<u8> = (0..65_536u32).map(|i| (i * 7 % 256) as u8).collect();
        let second = first[..40_000].to_vec();
        let mut frame = vec![0x04, 0x22, 0x4D, 0x18, 0x40, 0x40, 0];
        frame.extend((0x8000_0000u32 | first.len() as u32).to_le_bytes());
        frame.extend(&first);
        // The second block: compressed against the first as its dictionary (the window).
        let block = lz4_flex::block::compress_with_dict(&second, &first);
        frame.extend((block.len() as u32).to_le_bytes());
        frame.extend(&block);
        frame.extend(0u32.to_le_bytes());
        let expected: Vec<u8> = first.iter().chain(&second).copied().collect();
        assert!(block.len() < 1000, "the block refers back");
        assert_eq!(push(&frame, expected.len(), 100, 5000), expected);
    }

    #[test]
    fn damaged_frames_are_errors() {
        let mut decoder = Lz4Chunks::default();
        let mut out = [0u8; 16];
        assert!(decoder.decompress(b"not lz4 at all", &mut out).is_err());
        let mut decoder = Lz4Chunks::default();
        // A 64 KiB frame whose block claims 1 MiB.
        let mut frame = vec![0x04, 0x22, 0x4D, 0x18, 0x60, 0x40, 0];
        frame.extend((1u32 << 20).to_le_bytes());
        assert!(decoder.decompress(&frame, &mut out).is_err());
    }
}
