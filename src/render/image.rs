//! PNG encoding of frames and their visualisations: the RGB image, depth colour-mapped (near
//! bright yellow to far dark purple, background black) and the mask colour-coded by id.

use crate::files::{PngLevel, PngPixels, encode_png as encode};
use crate::render::raster::Frame;
use std::io::Write;

/// Errors while encoding or writing an image.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("writing {path}")]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("encoding PNG")]
    Png(#[from] png::EncodingError),
    #[error("image is {width}x{height} but has {bytes} bytes for {channels} channels")]
    Size {
        width: u32,
        height: u32,
        channels: u32,
        bytes: usize,
    },
}

impl crate::error::HasKind for ImageError {
    /// An output path in a missing or forbidden place is the user's to fix.
    fn kind(&self) -> crate::error::ErrorKind {
        use std::io::ErrorKind as Io;
        match self {
            ImageError::Io { source, .. }
                if matches!(
                    source.kind(),
                    Io::NotFound | Io::PermissionDenied | Io::IsADirectory | Io::NotADirectory
                ) =>
            {
                crate::error::ErrorKind::Usage
            }
            _ => crate::error::ErrorKind::Failed,
        }
    }
}

/// Encodes 8-bit RGB (3 channels) or grey (1 channel) pixels as PNG.
pub fn encode_png(
    width: u32,
    height: u32,
    channels: u32,
    pixels: &[u8],
    mut out: impl Write,
) -> Result<(), ImageError> {
    if pixels.len() != (width * height * channels) as usize || !matches!(channels, 1 | 3) {
        return Err(ImageError::Size {
            width,
            height,
            channels,
            bytes: pixels.len(),
        });
    }
    let layout = if channels == 3 {
        PngPixels::Rgb8
    } else {
        PngPixels::Grey8
    };
    let bytes = encode(
        width as usize,
        height as usize,
        layout,
        pixels,
        PngLevel::Fast,
    )?;
    out.write_all(&bytes)
        .map_err(|e| ImageError::Png(png::EncodingError::IoError(e)))
}

/// Writes a PNG file atomically (see [`crate::files::write_atomically`]): a crash never leaves
/// a truncated image under the final name.
pub fn write_png_file(
    path: &std::path::Path,
    width: u32,
    height: u32,
    channels: u32,
    pixels: &[u8],
) -> Result<(), ImageError> {
    let mut bytes = Vec::new();
    encode_png(width, height, channels, pixels, &mut bytes)?;
    crate::files::write_atomically(path, &bytes).map_err(|e| ImageError::Io {
        path: e.path,
        source: e.source,
    })?;
    Ok(())
}

/// A perceptual colour map (approximating "plasma") at t in [0, 1].
pub fn plasma(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [13.0, 8.0, 135.0],
        [126.0, 3.0, 168.0],
        [204.0, 71.0, 120.0],
        [248.0, 149.0, 64.0],
        [240.0, 249.0, 33.0],
    ];
    let x = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    [0, 1, 2].map(|c| (STOPS[i][c] + (STOPS[i + 1][c] - STOPS[i][c]) * f).round() as u8)
}

/// Depth as RGB: the nearest visible surface bright, the farthest dark, background black.
pub fn depth_visualisation(frame: &Frame) -> Vec<u8> {
    let valid = frame.depth_m.iter().copied().filter(|z| *z > 0.0);
    let (near, far) = valid.fold((f32::INFINITY, 0f32), |(lo, hi), z| (lo.min(z), hi.max(z)));
    let span = (far - near).max(1e-6);
    let (w, h) = (frame.width_px as usize, frame.height_px as usize);
    (0..w * h)
        .flat_map(|i| {
            let z = frame.depth_m[i];
            if z <= 0.0 {
                return [0, 0, 0];
            }
            let colour = plasma(1.0 - (z - near) / span);
            // Relief: a thin surface (at most 3 pixels across: a 1 mm needle wire on the pad)
            // with something deeper by more than RELIEF_M on both sides, 1 or 2 pixels away
            // along a row or a column, is drawn lighter, so thin objects show where the colour
            // scale cannot resolve them. An object's edge has a deeper side on one side only,
            // and a plane, however tilted, on neither: neither is outlined.
            let (u, v) = (i % w, i / w);
            let at = |uu: usize, vv: usize| frame.depth_m[vv * w + uu];
            let deeper = |d: f32| d > 0.0 && d - z > RELIEF_M;
            let thin = (1..=2).any(|k| {
                let across_row =
                    u >= k && u + k < w && deeper(at(u - k, v)) && deeper(at(u + k, v));
                let across_column =
                    v >= k && v + k < h && deeper(at(u, v - k)) && deeper(at(u, v + k));
                across_row || across_column
            });
            if thin {
                colour.map(|c| ((u16::from(c) + 255) / 2) as u8)
            } else {
                colour
            }
        })
        .collect()
}

/// Depth step that the depth visualisation outlines, metres.
const RELIEF_M: f32 = 0.0004;

/// A distinct colour for a mask id (0 is black).
pub fn mask_colour(id: u8) -> [u8; 3] {
    if id == 0 {
        return [0, 0, 0];
    }
    // Golden-angle hues at full saturation, two brightness levels.
    let hue = (f32::from(id) * 137.508).rem_euclid(360.0) / 60.0;
    let value = if id.is_multiple_of(2) { 255.0 } else { 200.0 };
    let c = value;
    let x = c * (1.0 - (hue.rem_euclid(2.0) - 1.0).abs());
    let (r, g, b) = match hue as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    [r as u8, g as u8, b as u8]
}

/// The mask colour-coded as RGB.
pub fn mask_visualisation(frame: &Frame) -> Vec<u8> {
    frame.mask.iter().flat_map(|id| mask_colour(*id)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_colours_are_distinct_for_the_first_ids() {
        let colours: Vec<[u8; 3]> = (0..32).map(mask_colour).collect();
        for i in 0..colours.len() {
            for j in 0..i {
                assert_ne!(colours[i], colours[j], "ids {i} and {j}");
            }
        }
    }

    #[test]
    fn png_rejects_a_wrong_size_and_encodes_a_right_one() {
        let mut bytes = Vec::new();
        assert!(encode_png(2, 2, 3, &[0; 11], &mut bytes).is_err());
        encode_png(2, 2, 3, &[7; 12], &mut bytes).expect("encode");
        assert_eq!(&bytes[1..4], b"PNG");
    }

    /// A `w` x `h` frame of `depth_m`, black, every pixel of mask id 1.
    fn depth_frame(w: u32, h: u32, depth_m: Vec<f32>) -> Frame {
        Frame {
            width_px: w,
            height_px: h,
            rgb: vec![0; (w * h * 3) as usize],
            depth_m,
            mask: vec![1; (w * h) as usize],
        }
    }

    #[test]
    fn the_depth_image_outlines_thin_relief_but_not_a_tilted_plane() {
        let (w, h) = (16u32, 16u32);
        // A plane 2 mm deeper per row, and a 1 mm ridge along column 8.
        let depth_m: Vec<f32> = (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                0.1 + 0.002 * v as f32 - if u == 8 { 0.001 } else { 0.0 }
            })
            .collect();
        let image = depth_visualisation(&depth_frame(w, h, depth_m));
        let brightness = |u: u32, v: u32| -> u32 {
            let i = ((v * w + u) * 3) as usize;
            image[i..i + 3].iter().map(|c| u32::from(*c)).sum()
        };
        // Along the plane's rows, neighbouring columns look alike; the ridge stands out.
        assert_eq!(
            brightness(4, 5),
            brightness(5, 5),
            "no outline on the plane"
        );
        assert!(
            brightness(8, 5) > brightness(7, 5) + 60,
            "the ridge is outlined"
        );
    }

    #[test]
    fn the_edges_of_a_wide_object_are_not_outlined_but_a_two_pixel_wire_is() {
        let (w, h) = (24u32, 8u32);
        // A block 5 mm proud over columns 4..12, a wire 1 mm proud over columns 16..18.
        let depth_m: Vec<f32> = (0..w * h)
            .map(|i| match i % w {
                4..12 => 0.095,
                16..18 => 0.099,
                _ => 0.1,
            })
            .collect();
        let image = depth_visualisation(&depth_frame(w, h, depth_m));
        let pixel = |u: u32| {
            let i = ((4 * w + u) * 3) as usize;
            [image[i], image[i + 1], image[i + 2]]
        };
        // The block's edge columns look like its middle: no white outline.
        assert_eq!(pixel(4), pixel(8));
        assert_eq!(pixel(11), pixel(8));
        // Both columns of the wire are drawn lighter than the colour of their depth alone.
        let colour = plasma(1.0 - (0.099 - 0.095) / 0.005);
        for u in [16, 17] {
            assert!(pixel(u).iter().zip(colour).all(|(p, c)| *p >= c), "{u}");
            assert_ne!(pixel(u), colour, "{u}");
        }
    }
}
