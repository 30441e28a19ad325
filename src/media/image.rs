//! Image encoding and decoding shared by every format: 8-bit PNG (RGB, grey masks) and 16-bit
//! grey PNG (RLDS depth in millimetres) here, float32 TIFF (depth in metres, LeRobot) in
//! [`crate::media::tiff`].

use crate::media::MediaError;

pub use crate::files::PngLevel;
use crate::files::PngPixels;

fn png_error(source: png::EncodingError) -> MediaError {
    MediaError::Encode {
        what: "PNG".into(),
        source: Box::new(source),
    }
}

/// Frame `i`'s stored bytes when the source kept them (`stored`, one per step), else `encode()`:
/// stored PNG bytes are copied rather than encoded again (lossless: the same pixels).
pub fn stored_or(
    stored: Option<&[crate::episode::EncodedFrame]>,
    i: usize,
    encode: impl FnOnce() -> Result<Vec<u8>, MediaError>,
) -> Result<Vec<u8>, MediaError> {
    match stored.and_then(|frames| frames.get(i)) {
        Some(frame) => Ok(frame.data.clone()),
        None => encode(),
    }
}

/// Encodes row-major 8-bit pixels with `channels` (1 = grey, 3 = RGB) as PNG.
pub fn encode_png(
    width: usize,
    height: usize,
    channels: usize,
    pixels: &[u8],
    level: PngLevel,
) -> Result<Vec<u8>, MediaError> {
    crate::files::encode_png(width, height, png_layout(channels)?, pixels, level).map_err(png_error)
}

/// [`encode_png`] appending to `out`.
pub fn encode_png_into(
    out: &mut Vec<u8>,
    width: usize,
    height: usize,
    channels: usize,
    pixels: &[u8],
    level: PngLevel,
) -> Result<(), MediaError> {
    let layout = png_layout(channels)?;
    crate::files::encode_png_into(out, width, height, layout, pixels, level).map_err(png_error)
}

/// The PNG layout of 8-bit pixels with `channels` (1 = grey, 3 = RGB, 4 = RGBA).
fn png_layout(channels: usize) -> Result<PngPixels, MediaError> {
    match channels {
        1 => Ok(PngPixels::Grey8),
        3 => Ok(PngPixels::Rgb8),
        4 => Ok(PngPixels::Rgba8),
        other => Err(MediaError::BadPixels(format!(
            "an image with {other} channels cannot be stored as PNG"
        ))),
    }
}

/// Encodes row-major 8-bit RGB as a baseline JPEG (4:2:0, `quality` 1-100) with integer
/// arithmetic only: the same bytes on every machine.
pub fn encode_jpeg(
    width: usize,
    height: usize,
    rgb: &[u8],
    quality: u8,
) -> Result<Vec<u8>, MediaError> {
    let encode_error = |source: jpeg_encoder::EncodingError| MediaError::Encode {
        what: "JPEG".into(),
        source: Box::new(source),
    };
    let (Ok(w), Ok(h)) = (u16::try_from(width), u16::try_from(height)) else {
        return Err(MediaError::BadPixels(format!(
            "a {width}x{height} image is too large for JPEG"
        )));
    };
    if rgb.len() != width * height * 3 {
        return Err(MediaError::BadPixels(format!(
            "{} bytes of RGB for a {width}x{height} image",
            rgb.len()
        )));
    }
    let mut out = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100));
    encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::F_2_2);
    encoder
        .encode(rgb, w, h, jpeg_encoder::ColorType::Rgb)
        .map_err(encode_error)?;
    Ok(out)
}

/// Whether `bytes` start like a JPEG (the SOI marker).
pub fn is_jpeg(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0xff, 0xd8, 0xff])
}

/// The largest image, in pixels, a JPEG of unknown size may claim before it is decoded.
pub const MAX_JPEG_PIXELS: usize = 8192 * 8192;

/// Decodes a JPEG of any size up to [`MAX_JPEG_PIXELS`] (its header read first) to 8-bit RGB or
/// grey: (width, height, channels, pixels).
pub fn decode_jpeg(bytes: &[u8]) -> Result<DecodedPng, String> {
    decode_jpeg_checked(bytes, None)
}

/// Decodes a JPEG of `expected` (width, height) to 8-bit RGB or grey: (width, height,
/// channels, pixels). A size other than expected is refused from the header, before decoding.
pub fn decode_jpeg_sized(bytes: &[u8], expected: (usize, usize)) -> Result<DecodedPng, String> {
    decode_jpeg_checked(bytes, Some(expected))
}

/// Reads the header, refuses a size other than `expected` (None: larger than
/// [`MAX_JPEG_PIXELS`]), then decodes.
fn decode_jpeg_checked(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
) -> Result<DecodedPng, String> {
    let mut decoder = jpeg_decoder::Decoder::new(bytes);
    decoder
        .read_info()
        .map_err(|e| format!("not a readable JPEG: {e}"))?;
    let info = decoder
        .info()
        .ok_or_else(|| "a JPEG without a frame header".to_string())?;
    let (width, height) = (usize::from(info.width), usize::from(info.height));
    match expected {
        Some(expected) if (width, height) != expected => {
            return Err(format!(
                "a {width}x{height} JPEG where {}x{} was declared",
                expected.0, expected.1
            ));
        }
        None if width * height > MAX_JPEG_PIXELS => {
            return Err(format!(
                "a {width}x{height} JPEG, larger than surgvla reads"
            ));
        }
        _ => {}
    }
    let channels = match info.pixel_format {
        jpeg_decoder::PixelFormat::RGB24 => 3,
        jpeg_decoder::PixelFormat::L8 => 1,
        other => return Err(format!("a JPEG of pixel format {other:?}")),
    };
    let pixels = decoder
        .decode()
        .map_err(|e| format!("not a readable JPEG: {e}"))?;
    if pixels.len() != width * height * channels {
        return Err("a JPEG that decodes to fewer pixels than its header says".into());
    }
    Ok((width as u32, height as u32, channels, pixels))
}

/// Encodes row-major 16-bit grey values as PNG (big-endian samples, as PNG stores them).
pub fn encode_png16(
    width: usize,
    height: usize,
    values: &[u16],
    level: PngLevel,
) -> Result<Vec<u8>, MediaError> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    crate::files::encode_png(width, height, PngPixels::Grey16, &bytes, level).map_err(png_error)
}

/// The widest and tallest image decoded: a header claiming more is refused before any pixel
/// memory is allocated (a 74-byte PNG can claim 100000 x 100000).
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// A PNG's (width, height) from its header, without decoding (None: not a readable PNG).
pub fn png_size(bytes: &[u8]) -> Option<(usize, usize)> {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let reader = decoder.read_info().ok()?;
    Some((reader.info().width as usize, reader.info().height as usize))
}

/// Decodes any PNG into its frame info and its samples as stored (16-bit ones big-endian). The
/// header is checked first: against `expected` (width, height) when given, and against
/// [`MAX_IMAGE_SIDE`] always, so that no claimed size is allocated before it is known to fit.
fn decode_png_raw(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
) -> Result<(png::OutputInfo, Vec<u8>), String> {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let (width, height) = (reader.info().width, reader.info().height);
    if let Some((w, h)) = expected
        && (width as usize, height as usize) != (w, h)
    {
        return Err(format!(
            "a {width}x{height} image where {w}x{h} was declared (not decoded)"
        ));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(format!(
            "a {width}x{height} image, larger than surgvla decodes ({MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE})"
        ));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| "the PNG is too large".to_string())?;
    let mut buffer = vec![0; size];
    let info = reader.next_frame(&mut buffer).map_err(|e| e.to_string())?;
    buffer.truncate(info.buffer_size());
    Ok((info, buffer))
}

/// Decodes a 16-bit grey PNG: (width, height, row-major values).
pub fn decode_png16(bytes: &[u8]) -> Result<(u32, u32, Vec<u16>), String> {
    decode_png16_sized(bytes, None)
}

/// [`decode_png16`] of an image declared `expected` (width, height): another size is refused
/// from the header, before decoding.
pub fn decode_png16_sized(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
) -> Result<(u32, u32, Vec<u16>), String> {
    let (info, buffer) = decode_png_raw(bytes, expected)?;
    if info.bit_depth != png::BitDepth::Sixteen || info.color_type != png::ColorType::Grayscale {
        return Err(format!(
            "a {:?}-bit {:?} PNG where 16-bit grey was expected",
            info.bit_depth, info.color_type
        ));
    }
    let values = buffer
        .chunks_exact(2)
        .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
        .collect();
    Ok((info.width, info.height, values))
}

/// A decoded 8-bit PNG: (width, height, channels, row-major pixels).
pub type DecodedPng = (u32, u32, usize, Vec<u8>);

/// Decodes an 8-bit image as stored, JPEG (by its signature) or PNG, of `expected` (width,
/// height) when given: another tool's image features hold either (a JPEG an RLDS dataset
/// stored, copied into LeRobot unchanged).
pub fn decode_8bit_sized(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
) -> Result<DecodedPng, String> {
    if is_jpeg(bytes) {
        decode_jpeg_checked(bytes, expected)
    } else {
        decode_png_sized(bytes, expected)
    }
}

/// Decodes an 8-bit grey, RGB or RGBA PNG.
pub fn decode_png(bytes: &[u8]) -> Result<DecodedPng, String> {
    decode_png_sized(bytes, None)
}

/// [`decode_png`] of an image declared `expected` (width, height): another size is refused from
/// the header, before decoding.
pub fn decode_png_sized(
    bytes: &[u8],
    expected: Option<(usize, usize)>,
) -> Result<DecodedPng, String> {
    let (info, buffer) = decode_png_raw(bytes, expected)?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!(
            "a {:?}-bit PNG where 8 bits were expected",
            info.bit_depth
        ));
    }
    let channels = info.color_type.samples();
    Ok((info.width, info.height, channels, buffer))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Another tool's image may be a JPEG or a PNG: both decode by their signature, sized as
    /// declared; a 16-bit PNG is not taken for 8 bits.
    #[test]
    fn eight_bit_images_decode_as_what_they_are() {
        let rgb: Vec<u8> = (0..8 * 6 * 3).map(|i| (i * 5) as u8).collect();
        let jpeg = encode_jpeg(8, 6, &rgb, 90).expect("jpeg");
        let png = encode_png(8, 6, 3, &rgb, PngLevel::Fast).expect("png");
        let (w, h, c, pixels) = decode_8bit_sized(&jpeg, Some((8, 6))).expect("jpeg decodes");
        assert_eq!((w, h, c, pixels.len()), (8, 6, 3, rgb.len()));
        assert_eq!(decode_8bit_sized(&png, Some((8, 6))).expect("png").3, rgb);
        assert!(decode_8bit_sized(&jpeg, Some((6, 8))).is_err());
        let deep = encode_png16(2, 2, &[1, 2, 3, 60_000], PngLevel::Fast).expect("png16");
        assert!(decode_8bit_sized(&deep, None).is_err_and(|e| e.contains("8 bits")));
    }

    #[test]
    fn jpeg_round_trips_near_the_pixels_with_the_same_bytes_everywhere() {
        let (width, height) = (40, 24);
        let rgb: Vec<u8> = (0..width * height)
            .flat_map(|i| {
                let (x, y) = (i % width, i / width);
                [(x * 6) as u8, (y * 9) as u8, ((x + y) * 3) as u8]
            })
            .collect();
        let jpeg = encode_jpeg(width, height, &rgb, 95).expect("encode");
        assert!(
            is_jpeg(&jpeg) && !is_jpeg(&encode_png(1, 1, 1, &[0], PngLevel::Fast).expect("png"))
        );
        // Integer arithmetic only: these bytes on every machine (a changed encoder or a SIMD
        // path that rounds differently fails here).
        assert_eq!(
            (jpeg.len(), crc32c::crc32c(&jpeg)),
            (SNAPSHOT_LEN, SNAPSHOT_CRC),
            "JPEG bytes changed"
        );
        let (w, h, channels, pixels) = decode_jpeg_sized(&jpeg, (width, height)).expect("decode");
        assert_eq!((w, h, channels), (40, 24, 3));
        let mean = pixels
            .iter()
            .zip(&rgb)
            .map(|(a, b)| f64::from(a.abs_diff(*b)))
            .sum::<f64>()
            / rgb.len() as f64;
        assert!(mean < 2.0, "mean difference {mean}");
        // Another size than declared is refused from the header; garbage is an error.
        assert!(
            decode_jpeg_sized(&jpeg, (24, 40))
                .unwrap_err()
                .contains("24x40")
        );
        assert!(decode_jpeg_sized(&jpeg[..jpeg.len() / 3], (40, 24)).is_err());
        assert!(encode_jpeg(width, height, &rgb[1..], 95).is_err());
    }

    const SNAPSHOT_LEN: usize = 954;
    const SNAPSHOT_CRC: u32 = 1_191_424_136;

    /// A valid PNG whose header claims `width` x `height` (the CRC fixed, the data not).
    fn forged(width: u32, height: u32) -> Vec<u8> {
        let mut png = encode_png(1, 1, 3, &[1, 2, 3], PngLevel::Fast).expect("encode");
        png[16..20].copy_from_slice(&width.to_be_bytes());
        png[20..24].copy_from_slice(&height.to_be_bytes());
        // CRC-32 (IEEE) of the IHDR chunk's type and data.
        let crc = !png[12..29].iter().fold(!0u32, |mut crc, &byte| {
            crc ^= u32::from(byte);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xedb8_8320
                } else {
                    crc >> 1
                };
            }
            crc
        });
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        png
    }

    #[test]
    fn a_header_claiming_a_huge_image_is_refused_before_allocating() {
        let bomb = forged(100_000, 100_000);
        assert!(bomb.len() < 100);
        assert_eq!(png_size(&bomb), Some((100_000, 100_000)));
        let error = decode_png(&bomb).unwrap_err();
        assert!(error.contains("larger than surgvla decodes"), "{error}");
        let error = decode_png_sized(&forged(300, 200), Some((224, 224))).unwrap_err();
        assert!(
            error.contains("300x200 image where 224x224 was declared"),
            "{error}"
        );
        assert!(decode_png16_sized(&forged(9000, 1), None).is_err());
    }

    #[test]
    fn png_round_trips_grey_and_rgb() {
        let rgb: Vec<u8> = (0..4 * 3 * 3).map(|i| (i * 7) as u8).collect();
        let encoded = encode_png(4, 3, 3, &rgb, PngLevel::Fast).expect("encode");
        assert_eq!(decode_png(&encoded).expect("decode"), (4, 3, 3, rgb));
        let grey = vec![1, 2, 3, 4];
        let encoded = encode_png(2, 2, 1, &grey, PngLevel::Best).expect("encode");
        assert_eq!(decode_png(&encoded).expect("decode"), (2, 2, 1, grey));
        assert!(encode_png(2, 2, 2, &[0; 8], PngLevel::Fast).is_err());
        assert!(decode_png(b"not a png").is_err());
    }

    #[test]
    fn png16_round_trips_and_refuses_8_bit() {
        let values = vec![0, 1, 255, 256, 40_000, u16::MAX];
        let encoded = encode_png16(3, 2, &values, PngLevel::Fast).expect("encode");
        assert_eq!(decode_png16(&encoded).expect("decode"), (3, 2, values));
        let eight = encode_png(2, 2, 1, &[1, 2, 3, 4], PngLevel::Fast).expect("encode");
        assert!(decode_png16(&eight).is_err());
        assert!(decode_png(&encoded).is_err());
    }
}
