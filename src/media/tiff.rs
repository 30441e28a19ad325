//! A minimal baseline TIFF encoder for single-channel float32 images (depth in metres):
//! little-endian, one uncompressed strip, `SampleFormat = IEEE float`. Pillow opens it as mode
//! "F", which LeRobot returns as float32 (1, H, W) in native units.

/// Encodes `pixels` (row-major, `width * height` values) as a float32 grey TIFF.
pub fn encode_f32_tiff(width: u32, height: u32, pixels: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(f32_tiff_len(pixels.len()));
    encode_f32_tiff_into(&mut out, width, height, pixels);
    out
}

/// The size of [`encode_f32_tiff`]'s file of `samples` values, bytes.
pub fn f32_tiff_len(samples: usize) -> usize {
    8 + 2 + 10 * 12 + 4 + samples * 4
}

/// [`encode_f32_tiff`] appending to `out`.
pub fn encode_f32_tiff_into(out: &mut Vec<u8>, width: u32, height: u32, pixels: &[f32]) {
    const ENTRIES: u16 = 10;
    let data_len = pixels.len() * 4;
    let ifd_offset = 8u32;
    let ifd_len = 2 + u32::from(ENTRIES) * 12 + 4;
    let data_offset = ifd_offset + ifd_len;
    out.reserve(data_offset as usize + data_len);
    out.extend_from_slice(b"II");
    out.extend_from_slice(&42u16.to_le_bytes());
    out.extend_from_slice(&ifd_offset.to_le_bytes());
    out.extend_from_slice(&ENTRIES.to_le_bytes());
    // (tag, type, count, value): type 3 = SHORT, 4 = LONG; entries sorted by tag.
    let entries: [(u16, u16, u32, u32); ENTRIES as usize] = [
        (256, 4, 1, width),           // ImageWidth
        (257, 4, 1, height),          // ImageLength
        (258, 3, 1, 32),              // BitsPerSample
        (259, 3, 1, 1),               // Compression: none
        (262, 3, 1, 1),               // PhotometricInterpretation: BlackIsZero
        (273, 4, 1, data_offset),     // StripOffsets
        (277, 3, 1, 1),               // SamplesPerPixel
        (278, 4, 1, height),          // RowsPerStrip
        (279, 4, 1, data_len as u32), // StripByteCounts
        (339, 3, 1, 3),               // SampleFormat: IEEE float
    ];
    for (tag, kind, count, value) in entries {
        out.extend_from_slice(&tag.to_le_bytes());
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&count.to_le_bytes());
        if kind == 3 {
            out.extend_from_slice(&(value as u16).to_le_bytes());
            out.extend_from_slice(&[0, 0]);
        } else {
            out.extend_from_slice(&value.to_le_bytes());
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes()); // no next IFD
    // Little-endian samples through a small buffer the compiler fills with vector copies, so
    // `out` is written once (not zeroed first).
    const SAMPLES: usize = 1024;
    let mut buffer = [0u8; SAMPLES * 4];
    for samples in pixels.chunks(SAMPLES) {
        let bytes = &mut buffer[..samples.len() * 4];
        for (bytes, v) in bytes.chunks_exact_mut(4).zip(samples) {
            bytes.copy_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(bytes);
    }
}

/// Decodes what [`encode_f32_tiff`] writes (our own round trip; the real reader is Pillow).
pub fn decode_f32_tiff(bytes: &[u8]) -> Option<(u32, u32, Vec<f32>)> {
    let (width, height, data) = f32_tiff_layout(bytes)?;
    let pixels = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Some((width, height, pixels))
}

/// A float32 grey TIFF's (width, height) when [`decode_f32_tiff`] would decode it, without
/// converting its samples (validate's size check).
pub fn f32_tiff_size(bytes: &[u8]) -> Option<(u32, u32)> {
    f32_tiff_layout(bytes).map(|(width, height, _)| (width, height))
}

/// (width, height, the samples' bytes) of a little-endian float32 grey TIFF in one strip.
fn f32_tiff_layout(bytes: &[u8]) -> Option<(u32, u32, &[u8])> {
    let u16_at = |o: usize| {
        bytes
            .get(o..o.checked_add(2)?)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    let u32_at = |o: usize| {
        bytes
            .get(o..o.checked_add(4)?)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    if bytes.get(0..4)? != b"II*\0" {
        return None;
    }
    let ifd = u32_at(4)? as usize;
    let count = u16_at(ifd)? as usize;
    let (mut width, mut height, mut offset, mut length, mut format, mut bits) = (0, 0, 0, 0, 0, 0);
    for i in 0..count {
        let entry = ifd + 2 + i * 12;
        let tag = u16_at(entry)?;
        let kind = u16_at(entry + 2)?;
        let value = if kind == 3 {
            u32::from(u16_at(entry + 8)?)
        } else {
            u32_at(entry + 8)?
        };
        match tag {
            256 => width = value,
            257 => height = value,
            258 => bits = value,
            273 => offset = value as usize,
            279 => length = value as usize,
            339 => format = value,
            _ => {}
        }
    }
    let samples_len = u64::from(width) * u64::from(height) * 4;
    if bits != 32 || format != 3 || length as u64 != samples_len {
        return None;
    }
    let data = bytes.get(offset..offset.checked_add(length)?)?;
    Some((width, height, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_bit_exact_and_rejects_garbage() {
        let pixels: Vec<f32> = (0..12).map(|i| i as f32 * 0.0137 - 0.01).collect();
        let bytes = encode_f32_tiff(4, 3, &pixels);
        let (w, h, back) = decode_f32_tiff(&bytes).expect("decodes");
        assert_eq!((w, h), (4, 3));
        assert_eq!(
            back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            pixels.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert!(decode_f32_tiff(b"not a tiff").is_none());
        assert!(decode_f32_tiff(&bytes[..bytes.len() - 1]).is_none());
        assert_eq!(f32_tiff_size(&bytes), Some((4, 3)));
        assert_eq!(f32_tiff_size(&bytes[..bytes.len() - 1]), None);
        // A claimed size whose byte count overflows 32 bits is refused, not wrapped.
        let mut huge = bytes.clone();
        let width_value = 8 + 2 + 8; // the first entry (width) holds its value at byte 8
        huge[width_value..width_value + 4].copy_from_slice(&0x4000_0001u32.to_le_bytes());
        assert_eq!(f32_tiff_size(&huge), None);
    }
}
