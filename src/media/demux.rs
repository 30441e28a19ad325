//! Reading MP4 video back without decoding it ([`re_mp4`]): the samples of a span of a file's
//! video track, in the form the muxer ([`crate::media::video::Mp4Writer`]) takes (AV1 OBUs,
//! H.264 Annex B), so video passes from one dataset to another unchanged.
//!
//! A span must start on a keyframe (every episode does: LeRobot and surgvla encode episodes
//! separately); a keyframe that leaves its parameters to the file's sample description (the
//! AV1 sequence header, H.264's SPS and PPS) gets them in-band, so the span stands alone in a
//! new file. Streams that reorder frames (B-frames) cannot be copied (their samples cannot be
//! appended by presentation time), only decoded: [`VideoReader::decodable`] gives a span's
//! samples in decode order from the keyframe before it, with their presentation times.

use crate::episode::{EncodedFrame, VideoCodec};
use crate::media::MediaError;
use crate::media::video::{obus, strip_temporal_delimiters};
use re_mp4::{Mp4, StsdBoxContent};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Slack when matching sample times to an episode's span, seconds (lerobot's own tolerance).
const TIME_TOLERANCE_SECS: f64 = 1e-4;

/// Bytes read at a time while the sample tables are parsed.
const TABLE_BUFFER_BYTES: usize = 1 << 16;

/// A sample's place in the file and its presentation time.
#[derive(Clone, Copy, Debug)]
struct SampleRef {
    /// The sample's number in the file, in decode order.
    index: usize,
    offset: u64,
    size: u64,
    time_secs: f64,
    keyframe: bool,
}

/// The video track of an MP4 file, ready to copy spans of.
pub struct VideoReader {
    path: PathBuf,
    file: File,
    pub codec: VideoCodec,
    pub width_px: u32,
    pub height_px: u32,
    /// Shared with readers [`VideoReader::reopen`] makes.
    samples: Arc<Vec<SampleRef>>,
    /// Positions in `samples` by presentation time ([`by_time`]), shared the same way.
    by_time: Arc<Vec<usize>>,
    /// What a keyframe lacking its parameters gets in front: the AV1 configuration OBUs, or
    /// H.264's SPS and PPS as Annex B.
    parameters: Arc<Vec<u8>>,
    /// H.264: bytes of each NAL unit's length prefix.
    length_size: usize,
    /// Whether presentation order differs from decode order (B-frames).
    pub reorders: bool,
    /// The episodes after the one read lie after its samples: the kernel reads them meanwhile.
    read_ahead: crate::files::ReadAhead,
}

/// A span's samples as a decoder needs them: in decode order, from a keyframe, with the
/// presentation times of the pictures they give, in presentation order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodableSpan {
    pub samples: Vec<EncodedFrame>,
    pub picture_secs: Vec<f64>,
}

fn invalid(path: &Path, problem: impl Into<String>) -> MediaError {
    MediaError::Invalid {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// The codec of a video track's sample description, the parameter sets its keyframes need
/// in-band (AV1's configuration OBUs, H.264's SPS and PPS in Annex B) and H.264's NAL length
/// size; another codec is refused as one surgvla does not read.
fn codec_of(
    path: &Path,
    contents: &StsdBoxContent,
) -> Result<(VideoCodec, Vec<u8>, usize), MediaError> {
    Ok(match contents {
        StsdBoxContent::Av01(av01) => (VideoCodec::Av1, av01.av1c.contents.config_obus.clone(), 0),
        StsdBoxContent::Avc1(avc1) => {
            let config = &avc1.avcc.contents;
            let mut parameters = Vec::new();
            for nal in config
                .sequence_parameter_sets
                .iter()
                .chain(&config.picture_parameter_sets)
            {
                parameters.extend_from_slice(&[0, 0, 0, 1]);
                parameters.extend_from_slice(&nal.bytes);
            }
            (
                VideoCodec::H264,
                parameters,
                usize::from(config.length_size_minus_one & 3) + 1,
            )
        }
        other => {
            // Not a defect of the file: a codec this build has no decoder for (exit 2).
            return Err(MediaError::Unsupported(format!(
                "{} holds {} video; surgvla reads AV1 and H.264 (no HEVC or VP9 decoder is built in)",
                path.display(),
                other.codec_string().unwrap_or_else(|| "unknown".into())
            )));
        }
    })
}

impl VideoReader {
    /// Reads the sample tables of the file's video track (not its media data).
    pub fn open(path: &Path) -> Result<Self, MediaError> {
        let file = crate::files::open_regular(path).map_err(MediaError::io(path))?;
        let size = file.metadata().map_err(MediaError::io(path))?.len();
        // The tables are read a few bytes at a time: buffered, not a system call each.
        let mut tables = std::io::BufReader::with_capacity(TABLE_BUFFER_BYTES, file);
        // re_mp4 trusts stsz's sample count and indexes its tables without bounds checks in
        // places: a damaged file must be an error naming it, never a crash or an abort.
        if let Some(problem) =
            crate::media::mp4scan::check_tables(&mut tables, size).map_err(MediaError::io(path))?
        {
            return Err(invalid(path, format!("not a readable MP4: {problem}")));
        }
        tables
            .seek(SeekFrom::Start(0))
            .map_err(MediaError::io(path))?;
        let parsed = crate::media::mp4scan::quietly(|| Mp4::read(&mut tables, size));
        let file = tables.into_inner();
        let mp4 = match parsed {
            Ok(Ok(mp4)) => mp4,
            Ok(Err(e)) => return Err(invalid(path, format!("not a readable MP4: {e}"))),
            Err(_) => return Err(invalid(path, "not a readable MP4 (damaged sample tables)")),
        };
        let track = mp4
            .tracks()
            .values()
            .find(|t| t.kind == Some(re_mp4::TrackKind::Video))
            .ok_or_else(|| invalid(path, "has no video track"))?;
        let trak = mp4
            .moov
            .traks
            .iter()
            .find(|t| t.tkhd.track_id == track.track_id)
            .ok_or_else(|| invalid(path, "has no video track"))?;
        let (codec, parameters, length_size) = codec_of(path, &trak.mdia.minf.stbl.stsd.contents)?;
        if track.timescale == 0 {
            return Err(invalid(path, "has a video track with time scale 0"));
        }
        let reorders = track
            .samples
            .iter()
            .any(|s| s.composition_timestamp != s.decode_timestamp);
        let samples = track
            .samples
            .iter()
            .enumerate()
            .map(|(index, s)| SampleRef {
                index,
                offset: s.offset,
                size: s.size,
                time_secs: s.composition_timestamp as f64 / track.timescale as f64,
                keyframe: s.is_sync,
            })
            .collect::<Vec<_>>();
        if let Some(bad) = samples
            .iter()
            .find(|s| s.offset.saturating_add(s.size) > size)
        {
            return Err(invalid(
                path,
                format!(
                    "a sample at byte {} runs past the end of the file ({size} bytes): truncated",
                    bad.offset
                ),
            ));
        }
        Ok(VideoReader {
            path: path.to_path_buf(),
            file,
            codec,
            width_px: u32::from(track.width),
            height_px: u32::from(track.height),
            by_time: Arc::new(by_time(&samples)),
            samples: Arc::new(samples),
            parameters: Arc::new(parameters),
            length_size,
            reorders,
            read_ahead: crate::files::ReadAhead::default(),
        })
    }

    /// Another reader of the same file with its own file handle, sharing the sample tables
    /// this one read (for workers reading spans of one file in parallel: the tables are parsed
    /// once).
    pub fn reopen(&self) -> Result<Self, MediaError> {
        Ok(VideoReader {
            path: self.path.clone(),
            file: crate::files::open_regular(&self.path).map_err(MediaError::io(&self.path))?,
            codec: self.codec,
            width_px: self.width_px,
            height_px: self.height_px,
            samples: Arc::clone(&self.samples),
            by_time: Arc::clone(&self.by_time),
            parameters: Arc::clone(&self.parameters),
            length_size: self.length_size,
            reorders: self.reorders,
            read_ahead: crate::files::ReadAhead::default(),
        })
    }

    /// Frames in the file.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The samples presented in `[from_secs, to_secs)`, in decode order.
    fn in_span(&self, from_secs: f64, to_secs: f64) -> impl Iterator<Item = &SampleRef> {
        (positions_in_span(&self.samples, &self.by_time, from_secs, to_secs).into_iter())
            .map(|i| &self.samples[i])
    }

    /// How many frames `[from_secs, to_secs)` holds, and whether the first is a keyframe (true
    /// when it holds none), without reading them.
    pub fn count_span(&self, from_secs: f64, to_secs: f64) -> (usize, bool) {
        let mut samples = self.in_span(from_secs, to_secs);
        let first_key = samples.next().is_none_or(|s| s.keyframe);
        let count = self.in_span(from_secs, to_secs).count();
        (count, first_key)
    }

    /// The frames presented in `[from_secs, to_secs)`, ready to append to another file; the
    /// first must be a keyframe.
    pub fn span(&mut self, from_secs: f64, to_secs: f64) -> Result<Vec<EncodedFrame>, MediaError> {
        if self.reorders {
            return Err(invalid(
                &self.path,
                "reorders frames (B-frames), which surgvla cannot copy between files: decode them (convert --decode for images, or --video with another codec than the input's to re-encode them)",
            ));
        }
        let wanted: Vec<SampleRef> = self.in_span(from_secs, to_secs).copied().collect();
        if wanted.first().is_some_and(|s| !s.keyframe) {
            return Err(invalid(
                &self.path,
                format!(
                    "the span {from_secs:.4}..{to_secs:.4} s does not start on a keyframe, so it cannot be copied alone"
                ),
            ));
        }
        self.frames(&wanted)
    }

    /// The presentation times (seconds) of the frames [`Self::span`] returns, in its order.
    pub fn span_times(&self, from_secs: f64, to_secs: f64) -> Vec<f64> {
        self.in_span(from_secs, to_secs)
            .map(|s| s.time_secs)
            .collect()
    }

    /// The samples a decoder needs for the pictures presented in `[from_secs, to_secs)`: in
    /// decode order, from the keyframe at or before the first of them to the last of them, and
    /// the presentation times of every picture they give (sorted). Empty when the span holds
    /// no picture.
    pub fn decodable(&mut self, from_secs: f64, to_secs: f64) -> Result<DecodableSpan, MediaError> {
        let inside = positions_in_span(&self.samples, &self.by_time, from_secs, to_secs);
        let (Some(&first), Some(&last)) = (inside.first(), inside.last()) else {
            return Ok(DecodableSpan::default());
        };
        let Some(start) = self.samples[..=first].iter().rposition(|s| s.keyframe) else {
            return Err(invalid(
                &self.path,
                format!("no keyframe precedes the span {from_secs:.4}..{to_secs:.4} s"),
            ));
        };
        let wanted: Vec<SampleRef> = self.samples[start..=last].to_vec();
        let mut picture_secs: Vec<f64> = wanted.iter().map(|s| s.time_secs).collect();
        picture_secs.sort_by(f64::total_cmp);
        let samples = self.frames(&wanted)?;
        Ok(DecodableSpan {
            samples,
            picture_secs,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Every frame of the file.
    pub fn all(&mut self) -> Result<Vec<EncodedFrame>, MediaError> {
        self.span(f64::NEG_INFINITY, f64::INFINITY)
    }

    /// The frames of `samples`: read in one go when they lie close together (an episode's, as
    /// writers interleave nothing else), each on its own otherwise.
    fn frames(&mut self, samples: &[SampleRef]) -> Result<Vec<EncodedFrame>, MediaError> {
        let start = samples.iter().map(|s| s.offset).min().unwrap_or(0);
        let end = (samples.iter().map(|s| s.offset.saturating_add(s.size)))
            .max()
            .unwrap_or(0);
        let wanted: u64 = samples.iter().map(|s| s.size).sum();
        let span = end.saturating_sub(start);
        if samples.len() < 2 || span > wanted.saturating_mul(2).saturating_add(1 << 16) {
            return (samples.iter())
                .map(|s| {
                    let bytes = self.read(s.offset, s.size)?;
                    self.frame(s, &bytes)
                })
                .collect();
        }
        self.read_ahead.reading(&self.file, end, u64::MAX);
        let all = self.read(start, span)?;
        (samples.iter())
            .map(|s| {
                // Inside the span by its construction.
                let from = (s.offset - start) as usize;
                self.frame(s, &all[from..from + s.size as usize])
            })
            .collect()
    }

    /// `size` bytes at `offset` (inside the file: every sample was checked to be).
    fn read(&mut self, offset: u64, size: u64) -> Result<Vec<u8>, MediaError> {
        let mut bytes = vec![0u8; size as usize];
        self.file
            .seek(SeekFrom::Start(offset))
            .and_then(|_| self.file.read_exact(&mut bytes))
            .map_err(MediaError::io(&self.path))?;
        Ok(bytes)
    }

    /// `sample` as a decoder takes it, from its stored `bytes`.
    fn frame(&self, sample: &SampleRef, bytes: &[u8]) -> Result<EncodedFrame, MediaError> {
        let data = match self.codec {
            VideoCodec::Av1 => {
                let obus = strip_temporal_delimiters(bytes);
                if sample.keyframe && !has_av1_sequence_header(&obus) {
                    [self.parameters.as_slice(), &obus].concat()
                } else {
                    obus
                }
            }
            VideoCodec::H264 => {
                let annex_b = avcc_to_annex_b(bytes, self.length_size).ok_or_else(|| {
                    invalid(
                        &self.path,
                        format!(
                            "sample {} (at byte {}) is not length-prefixed H.264: a NAL unit runs past its end",
                            sample.index, sample.offset
                        ),
                    )
                })?;
                if sample.keyframe && !has_h264_sps(&annex_b) {
                    [self.parameters.as_slice(), &annex_b].concat()
                } else {
                    annex_b
                }
            }
        };
        Ok(EncodedFrame {
            data,
            keyframe: sample.keyframe,
        })
    }
}

/// Whether an AV1 temporal unit holds a sequence header OBU (type 1).
fn has_av1_sequence_header(data: &[u8]) -> bool {
    obus(data).is_some_and(|spans| spans.iter().any(|(kind, _)| *kind == 1))
}

/// Length-prefixed NAL units (`length_size` bytes each) as Annex B (4-byte start codes).
fn avcc_to_annex_b(data: &[u8], length_size: usize) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(data.len() + 16);
    let mut i = 0;
    while i < data.len() {
        let prefix = data.get(i..i + length_size)?;
        let length = prefix
            .iter()
            .fold(0usize, |acc, b| (acc << 8) | usize::from(*b));
        i += length_size;
        let nal = data.get(i..i.checked_add(length)?)?;
        out.extend_from_slice(&[0, 0, 0, 1]);
        out.extend_from_slice(nal);
        i += length;
    }
    Some(out)
}

/// Whether Annex B bytes hold a sequence parameter set (NAL type 7).
fn has_h264_sps(annex_b: &[u8]) -> bool {
    annex_b
        .windows(4)
        .any(|w| w[..3] == [0, 0, 1] && w[3] & 0x1f == 7)
}

/// The positions of `samples` in order of presentation time (ties in decode order), those
/// without a time (NaN) left out: what [`positions_in_span`] searches.
fn by_time(samples: &[SampleRef]) -> Vec<usize> {
    let mut positions: Vec<usize> = (0..samples.len())
        .filter(|&i| !samples[i].time_secs.is_nan())
        .collect();
    positions.sort_by(|&a, &b| samples[a].time_secs.total_cmp(&samples[b].time_secs));
    positions
}

/// The positions (decode order) of the samples presented in `[from_secs, to_secs)`, within
/// [`TIME_TOLERANCE_SECS`]: two binary searches of `by_time` (from [`by_time`]), not a pass
/// over every sample of the file for each episode's span.
fn positions_in_span(
    samples: &[SampleRef],
    by_time: &[usize],
    from_secs: f64,
    to_secs: f64,
) -> Vec<usize> {
    let (low, high) = (
        from_secs - TIME_TOLERANCE_SECS,
        to_secs - TIME_TOLERANCE_SECS,
    );
    if low.is_nan() || high.is_nan() {
        // No time is at or after NaN.
        return Vec::new();
    }
    let before = |low: f64| by_time.partition_point(|&i| samples[i].time_secs < low);
    let (start, end) = (before(low), before(high));
    let mut positions = by_time.get(start..end).unwrap_or_default().to_vec();
    positions.sort_unstable();
    positions
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::video::{Mp4Writer, encode};

    /// The binary searches find exactly the samples a pass over all of them finds, in decode
    /// order: seeded files of times out of order, repeated, negative, NaN and infinite.
    #[test]
    fn spans_found_by_time_are_those_a_pass_finds() {
        let mut rng = crate::rng::SplitMix64::stream(5, "sample times");
        let odd = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, 0.0];
        for case in 0..300 {
            let count = (rng.next_u64() % 40) as usize;
            let samples: Vec<SampleRef> = (0..count)
                .map(|index| SampleRef {
                    index,
                    offset: 0,
                    size: 0,
                    time_secs: match rng.next_u64() % 6 {
                        0 => odd[(rng.next_u64() % odd.len() as u64) as usize],
                        1 => (rng.next_u64() % 5) as f64 * 0.2,
                        _ => rng.uniform(-1.0, 9.0),
                    },
                    keyframe: true,
                })
                .collect();
            let sorted = by_time(&samples);
            for _ in 0..20 {
                let mut bound = || match rng.next_u64() % 5 {
                    0 => odd[(rng.next_u64() % odd.len() as u64) as usize],
                    1 => (rng.next_u64() % 5) as f64 * 0.2 + TIME_TOLERANCE_SECS,
                    _ => rng.uniform(-2.0, 10.0),
                };
                let (from, to) = (bound(), bound());
                let passed: Vec<usize> = (0..count)
                    .filter(|&i| {
                        let t = samples[i].time_secs;
                        t >= from - TIME_TOLERANCE_SECS && t < to - TIME_TOLERANCE_SECS
                    })
                    .collect();
                let found = positions_in_span(&samples, &sorted, from, to);
                assert_eq!(found, passed, "case {case}: {from}..{to}");
            }
        }
    }

    fn frames(n: u8) -> Vec<Vec<u8>> {
        (0..n)
            .map(|i| {
                (0..64 * 48 * 3)
                    .map(|k| ((k / 7) as u8).wrapping_add(i * 11))
                    .collect()
            })
            .collect()
    }

    /// Encodes `frames` twice into one MP4 (two "episodes"), reads both spans back, and
    /// re-muxes them: the copy is byte-identical to the original.
    fn round_trip(codec: VideoCodec) {
        let root = std::env::temp_dir().join(format!(
            "surgvla-demux-{}-{}",
            codec.name(),
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).expect("dir");
        let pixels = frames(5);
        let refs: Vec<&[u8]> = pixels.iter().map(|f| f.as_slice()).collect();
        let encoded = encode(codec, &refs, 64, 48, 10, 30).expect("encode");
        let write = |name: &str, episodes: &[&[EncodedFrame]]| {
            let path = root.join(name);
            let file = File::create(&path).expect("file");
            let mut video = Mp4Writer::create(file, path, codec, (64, 48), 10).expect("video");
            let spans: Vec<(f64, f64)> = episodes
                .iter()
                .map(|e| video.append(e).expect("append"))
                .collect();
            // What the writer counts (its rolling rule) is every sample's bytes, although the
            // muxer keeps them in memory until it finishes: the file's size less its boxes.
            let counted = video.bytes_written();
            let samples: usize = episodes
                .iter()
                .flat_map(|e| e.iter())
                .map(|f| f.data.len())
                .sum();
            video.finish().expect("finish");
            let size = std::fs::metadata(root.join(name)).expect("size").len();
            assert_eq!(counted, samples as u64);
            assert!(counted > 0 && counted < size, "{counted} of {size}");
            spans
        };
        let spans = write("a.mp4", &[&encoded, &encoded]);
        let mut reader = VideoReader::open(&root.join("a.mp4")).expect("open");
        assert_eq!(
            (reader.codec, reader.width_px, reader.len()),
            (codec, 64, 10)
        );
        let second = reader.span(spans[1].0, spans[1].1).expect("span");
        assert_eq!(second.len(), 5);
        assert!(second[0].keyframe);
        let first = reader.span(spans[0].0, spans[0].1).expect("span");
        // Read in one go or sample by sample, the same frames.
        let wanted: Vec<SampleRef> = reader.in_span(spans[0].0, spans[0].1).copied().collect();
        let one_by_one: Vec<EncodedFrame> = (wanted.iter())
            .map(|s| {
                reader
                    .frames(std::slice::from_ref(s))
                    .expect("frame")
                    .remove(0)
            })
            .collect();
        assert_eq!(first, one_by_one);
        write("b.mp4", &[&first, &second]);
        assert_eq!(
            std::fs::read(root.join("a.mp4")).expect("a"),
            std::fs::read(root.join("b.mp4")).expect("b")
        );
        // The second episode alone starts a valid file of its own.
        write("c.mp4", &[&second]);
        let alone = VideoReader::open(&root.join("c.mp4"))
            .expect("open")
            .all()
            .expect("all");
        assert_eq!(alone, second);
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn av1_spans_copy_byte_for_byte() {
        round_trip(VideoCodec::Av1);
    }

    #[test]
    fn h264_spans_copy_byte_for_byte() {
        round_trip(VideoCodec::H264);
    }

    #[test]
    fn garbage_is_an_error_naming_the_file() {
        let path =
            std::env::temp_dir().join(format!("surgvla-demux-bad-{}.mp4", std::process::id()));
        let mut rng = crate::rng::SplitMix64::stream(1, "demux garbage");
        for round in 0..50 {
            let mut bytes: Vec<u8> = (0..200 + round * 13)
                .map(|_| rng.next_u64() as u8)
                .collect();
            if round % 2 == 0 {
                // A plausible box header first.
                bytes[..8].copy_from_slice(&[0, 0, 0, 24, b'f', b't', b'y', b'p']);
            }
            std::fs::write(&path, &bytes).expect("write");
            let error = VideoReader::open(&path).err().expect("garbage is refused");
            assert!(
                error.to_string().contains(&*path.to_string_lossy()),
                "{error}"
            );
        }
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn avcc_becomes_annex_b() {
        let avcc = [0, 0, 0, 2, 0x67, 1, 0, 0, 0, 1, 0x65];
        assert_eq!(
            avcc_to_annex_b(&avcc, 4),
            Some(vec![0, 0, 0, 1, 0x67, 1, 0, 0, 0, 1, 0x65])
        );
        assert_eq!(avcc_to_annex_b(&[0, 0, 0, 9, 1], 4), None);
        assert!(has_h264_sps(&[0, 0, 0, 1, 0x67, 1]));
        assert!(!has_h264_sps(&[0, 0, 0, 1, 0x65, 1]));
    }
}
