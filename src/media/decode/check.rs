//! `validate`'s decoding pass over a video span: every sample decodes (the first only, quick),
//! to the frame size the dataset declares. What the decoders cannot read (another codec, an
//! H.264 profile or AV1 layout surgvla does not decode) is reported as unsupported, which
//! `validate` makes a warning, never a finding.

use super::{MAX_DECODED_SIDE_PX, decode_span_each};
use crate::error::{ErrorKind, HasKind};
use crate::media::MediaError;
use crate::media::demux::VideoReader;

/// What decoding a span found.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodeProblem {
    /// The frame (in presentation order, counted from the span's first decoded picture) where
    /// it was found; None for the span as a whole.
    pub frame: Option<u64>,
    pub message: String,
    /// Surgvla cannot decode this stream (not a defect of the data).
    pub unsupported: bool,
}

fn problem(frame: Option<u64>, error: &MediaError) -> DecodeProblem {
    DecodeProblem {
        frame,
        message: crate::error::chain(error),
        unsupported: error.kind() == ErrorKind::Usage,
    }
}

/// Decodes the pictures of `video`'s file presented in `span` (seconds; None: the whole file),
/// or only the first when `quick`, and checks each is `size_px` (width, height); with `means`,
/// also returns the decoded RGB frames' mean per channel (0..1) when every picture decoded.
/// `video` is a reader whose tables are shared ([`VideoReader::reopen`]): one per file, however
/// many episodes it holds. `on_picture` sees each decoded picture in presentation order. The
/// first failure ends the pass.
pub fn check_span(
    video: &VideoReader,
    span: Option<(f64, f64)>,
    size_px: (usize, usize),
    quick: bool,
    means: bool,
    on_picture: &mut dyn FnMut(&super::YuvFrame),
) -> (Vec<DecodeProblem>, Option<[f64; 3]>) {
    let mut reader = match video.reopen() {
        Ok(reader) => reader,
        Err(error) => return (vec![problem(None, &error)], None),
    };
    let (from, to) = span.unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
    let mut samples = match reader.decodable(from, to) {
        Ok(decodable) => decodable.samples,
        Err(error) => return (vec![problem(None, &error)], None),
    };
    let mut sums = [0u64; 3];
    let mut pixels = 0u64;
    if quick {
        samples.truncate(1);
    }
    let mut problems = Vec::new();
    let mut frame = 0u64;
    let what = reader.path().display().to_string();
    let decoded = decode_span_each(
        reader.codec,
        &samples,
        &what,
        MAX_DECODED_SIDE_PX,
        &mut |picture| {
            let size = (picture.width_px as usize, picture.height_px as usize);
            if size != size_px && problems.len() < 3 {
                problems.push(DecodeProblem {
                    frame: Some(frame),
                    message: format!(
                        "decodes to a {}x{} frame where {}x{} is declared",
                        size.0, size.1, size_px.0, size_px.1
                    ),
                    unsupported: false,
                });
            }
            if means && let Some(rgb) = super::rgb_from_yuv420(&picture) {
                for pixel in rgb.chunks_exact(3) {
                    for (sum, value) in sums.iter_mut().zip(pixel) {
                        *sum += u64::from(*value);
                    }
                }
                pixels += (rgb.len() / 3) as u64;
            }
            on_picture(&picture);
            frame += 1;
            Ok(())
        },
    );
    if let Err(error) = decoded {
        let mut found = problem(Some(frame), &error);
        found.message = format!("frame {frame} does not decode: {}", found.message);
        problems.push(found);
        return (problems, None);
    }
    let mean = (means && pixels > 0).then(|| sums.map(|s| s as f64 / pixels as f64 / 255.0));
    (problems, mean)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks a fixture file as a whole (no means): its problems.
    fn check(name: &str, size_px: (usize, usize), quick: bool) -> Vec<DecodeProblem> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/video")
            .join(name);
        let video = VideoReader::open(&path).expect("open");
        check_span(&video, None, size_px, quick, false, &mut |_| {}).0
    }

    #[test]
    fn good_files_decode_and_damaged_ones_are_named_with_their_frame() {
        for name in ["svtav1_g2.mp4", "x264_high_bframes.mp4"] {
            assert_eq!(check(name, (64, 48), false), vec![]);
            // The declared size is checked against the decoded one.
            let wrong = check(name, (32, 24), true);
            assert_eq!(wrong.len(), 1, "{wrong:?}");
            assert!(
                wrong[0]
                    .message
                    .contains("decodes to a 64x48 frame where 32x24")
            );
        }
        // Corrupted bytes in the sixth sample: the first five decode.
        let corrupt = check("svtav1_corrupt_sample.mp4", (64, 48), false);
        assert_eq!(corrupt.len(), 1, "{corrupt:?}");
        assert_eq!(corrupt[0].frame, Some(5));
        assert!(!corrupt[0].unsupported);
        assert!(corrupt[0].message.contains("svtav1_corrupt_sample.mp4"));
        // The quick pass decodes the first frame only, which is intact.
        assert_eq!(check("svtav1_corrupt_sample.mp4", (64, 48), true), vec![]);
        // A sample whose NAL unit claims more bytes than it holds.
        let truncated = check("x264_truncated_sample.mp4", (64, 48), false);
        assert_eq!(truncated.len(), 1, "{truncated:?}");
        assert!(truncated[0].message.contains("sample 3"), "{truncated:?}");
        // Coded at 32x24 in a file that says 64x48.
        let size = check("svtav1_wrong_size.mp4", (64, 48), false);
        assert!(!size.is_empty(), "{size:?}");
        assert!(size[0].message.contains("32x24"), "{size:?}");
    }
}
