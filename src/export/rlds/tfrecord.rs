//! TFRecord framing, the container of RLDS shards (no file header, no compression):
//! per record `u64 LE length | u32 LE masked CRC-32C of the length bytes | data | u32 LE masked
//! CRC-32C of the data`. [`write_record`] frames one record; [`RecordReader`] reads them back
//! and rejects a flipped byte or a truncated record, as TensorFlow's reader does.

use std::io::{Read, Write};

/// TFRecord's CRC mask: `((c >> 15) | (c << 17)) + 0xA282EAD8` (mod 2^32).
pub fn masked_crc32c(bytes: &[u8]) -> u32 {
    let crc = crc32c::crc32c(bytes);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// Bytes a record of `data_len` bytes takes in a shard.
pub fn framed_len(data_len: usize) -> u64 {
    data_len as u64 + 16
}

/// Writes one framed record.
pub fn write_record(out: &mut impl Write, data: &[u8]) -> std::io::Result<()> {
    let length = (data.len() as u64).to_le_bytes();
    out.write_all(&length)?;
    out.write_all(&masked_crc32c(&length).to_le_bytes())?;
    out.write_all(data)?;
    out.write_all(&masked_crc32c(data).to_le_bytes())
}

/// What is wrong with a record being read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("reading record {index}")]
    Io {
        index: u64,
        #[source]
        source: std::io::Error,
    },
    #[error("record {index} is truncated ({what})")]
    Truncated { index: u64, what: &'static str },
    #[error("record {index}: the CRC of its {what} does not match (the file is corrupt)")]
    Crc { index: u64, what: &'static str },
}

/// Reads framed records one at a time, checking both CRCs.
pub struct RecordReader<R> {
    input: R,
    index: u64,
}

impl<R: Read> RecordReader<R> {
    pub fn new(input: R) -> Self {
        RecordReader { input, index: 0 }
    }

    /// Fills `buffer`; false on a clean end of input before any byte.
    fn read_exact_or_end(
        &mut self,
        buffer: &mut [u8],
        what: &'static str,
    ) -> Result<bool, RecordError> {
        let mut filled = 0;
        while filled < buffer.len() {
            match self.input.read(&mut buffer[filled..]) {
                Ok(0) if filled == 0 && what == "length" => return Ok(false),
                Ok(0) => {
                    return Err(RecordError::Truncated {
                        index: self.index,
                        what,
                    });
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(RecordError::Io {
                        index: self.index,
                        source,
                    });
                }
            }
        }
        Ok(true)
    }

    /// The next record's data, or None after the last.
    pub fn next_record(&mut self) -> Option<Result<Vec<u8>, RecordError>> {
        let mut header = [0u8; 12];
        match self.read_exact_or_end(&mut header, "length") {
            Ok(false) => return None,
            Ok(true) => {}
            Err(e) => return Some(Err(e)),
        }
        let (length, crc) = header.split_at(8);
        let crc = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
        if masked_crc32c(length) != crc {
            return Some(Err(RecordError::Crc {
                index: self.index,
                what: "length",
            }));
        }
        let mut length_bytes = [0u8; 8];
        length_bytes.copy_from_slice(length);
        let length = u64::from_le_bytes(length_bytes);
        let mut data = Vec::new();
        if let Err(source) = (&mut self.input).take(length).read_to_end(&mut data) {
            return Some(Err(RecordError::Io {
                index: self.index,
                source,
            }));
        }
        if data.len() as u64 != length {
            return Some(Err(RecordError::Truncated {
                index: self.index,
                what: "data",
            }));
        }
        let mut footer = [0u8; 4];
        if let Err(e) = self.read_exact_or_end(&mut footer, "data CRC") {
            return Some(Err(e));
        }
        if masked_crc32c(&data) != u32::from_le_bytes(footer) {
            return Some(Err(RecordError::Crc {
                index: self.index,
                what: "data",
            }));
        }
        self.index += 1;
        Some(Ok(data))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn framed(data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        write_record(&mut out, data).expect("write");
        out
    }

    #[test]
    fn framing_matches_the_spec_test_vectors() {
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(
            framed(b""),
            [
                0, 0, 0, 0, 0, 0, 0, 0, 0x29, 0x03, 0x98, 0x07, 0xd8, 0xea, 0x82, 0xa2
            ]
        );
        assert_eq!(
            framed(b"hello"),
            [
                5, 0, 0, 0, 0, 0, 0, 0, 0xea, 0xb2, 0x04, 0x3e, b'h', b'e', b'l', b'l', b'o', 0xbb,
                0x1f, 0x1c, 0x19
            ]
        );
        assert_eq!(framed(b"hello").len() as u64, framed_len(5));
    }

    #[test]
    fn records_read_back_and_corruption_is_caught() {
        let mut shard = framed(b"first");
        shard.extend(framed(b""));
        shard.extend(framed(&[7u8; 300]));
        let mut reader = RecordReader::new(shard.as_slice());
        let records: Vec<Vec<u8>> = std::iter::from_fn(|| reader.next_record())
            .collect::<Result<_, _>>()
            .expect("read");
        assert_eq!(records, [b"first".to_vec(), Vec::new(), vec![7u8; 300]]);

        for flip in [3usize, 9, 14, shard.len() - 2] {
            let mut bad = shard.clone();
            bad[flip] ^= 0x01;
            let mut reader = RecordReader::new(bad.as_slice());
            let error = std::iter::from_fn(|| reader.next_record())
                .find_map(Result::err)
                .unwrap_or_else(|| panic!("a flipped byte at {flip} went unnoticed"));
            assert!(
                matches!(
                    error,
                    RecordError::Crc { .. } | RecordError::Truncated { .. }
                ),
                "{error}"
            );
        }
        let truncated = &shard[..shard.len() - 5];
        let mut reader = RecordReader::new(truncated);
        let error = std::iter::from_fn(|| reader.next_record())
            .find_map(Result::err)
            .expect("truncation caught");
        assert!(
            matches!(error, RecordError::Truncated { index: 2, .. }),
            "{error}"
        );
    }
}
