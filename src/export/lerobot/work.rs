//! The per-episode work that needs only the dataset's features and options, so it runs on rayon
//! threads while the writer holds its non-shareable parquet state: image encoding (PNG, TIFF),
//! video encoding, and the episode's statistics.

use super::LeRobotOptions;
use super::table::{DEFAULT_COLUMNS, EncodedImages};
use crate::episode::{
    Dtype, Episode, FeatureKind, FeatureSpec, FeatureValue, ImageEncoding, PixelStats, VideoCodec,
};
use crate::export::ExportError;
use crate::export::image::{decode_png, encode_png};
use crate::export::info::DatasetInfo;
use crate::export::stats::{FeatureStats, ImageStats, SummaryStats, VectorStats};
use crate::export::tiff::encode_f32_tiff;
use crate::export::video::{EncodedFrame, encode};
use rayon::prelude::*;

/// Statistics per feature, then per default column, in column order.
pub(super) type EpisodeStats = Vec<(String, FeatureStats)>;

/// Empty statistics for `features` and the default columns.
pub(super) fn fresh_stats(features: &[FeatureSpec]) -> EpisodeStats {
    let mut stats: EpisodeStats = features
        .iter()
        .map(|f| (f.name.clone(), FeatureStats::for_feature(f)))
        .collect();
    stats.extend(
        DEFAULT_COLUMNS
            .iter()
            .map(|name| (name.to_string(), FeatureStats::scalar())),
    );
    stats
}

pub struct EpisodeWork<'a> {
    /// Frames in parallel (false: the caller is one of many threads each working on an
    /// episode, where nested parallelism would only make them wait on each other).
    pub parallel: bool,
    pub info: &'a DatasetInfo,
    /// The features stored in the parquet (all but the video ones).
    pub parquet_features: &'a [FeatureSpec],
    /// The features stored as video, with their codec, in feature order.
    pub video_features: &'a [(String, VideoCodec)],
    pub options: &'a LeRobotOptions,
}

impl EpisodeWork<'_> {
    /// Each video feature's frames, in [`EpisodeWork::video_features`] order: copied when the
    /// episode brings them in the feature's codec, else (the RGB camera in video mode) encoded
    /// from its pixels.
    pub fn video_frames(&self, episode: &Episode) -> Result<Vec<Vec<EncodedFrame>>, ExportError> {
        self.video_features
            .iter()
            .map(|(key, codec)| {
                if let Some(stored) = episode.encoded_video(key) {
                    if stored.encoding != ImageEncoding::Video(*codec) {
                        return Err(ExportError::InvalidEpisode(format!(
                            "episode {}: {key} arrived as {:?} where this dataset stores {} video (surgvla does not decode video to encode it again)",
                            episode.meta.index,
                            stored.encoding,
                            codec.name()
                        )));
                    }
                    return Ok(stored.frames.clone());
                }
                let quality = self.options.video.map_or(0, |v| v.quality);
                // Another dataset's camera: its PNGs decoded (they came from decoded video, or
                // an image-mode dataset), then encoded.
                let others = self
                    .info
                    .features
                    .iter()
                    .filter(|f| f.kind == FeatureKind::Other && f.in_steps());
                if let Some((at, feature)) = others.enumerate().find(|(_, f)| f.name == *key) {
                    let (height, width) = (feature.shape[0], feature.shape[1]);
                    let pixels = episode
                        .steps
                        .iter()
                        .enumerate()
                        .map(|(i, step)| other_rgb(step, at, width, height, key, i))
                        .collect::<Result<Vec<Vec<u8>>, ExportError>>()?;
                    let frames: Vec<&[u8]> = pixels.iter().map(Vec::as_slice).collect();
                    return encode(*codec, &frames, width, height, self.info.fps, quality);
                }
                let (width, height) = self.info.image_size();
                let frames: Vec<&[u8]> = episode.steps.iter().map(|s| s.rgb.as_slice()).collect();
                encode(*codec, &frames, width, height, self.info.fps, quality)
            })
            .collect()
    }

    /// Encodes every image stored in the parquet (frames in parallel, order kept).
    pub fn encode_images(&self, episode: &Episode) -> Result<EncodedImages, ExportError> {
        let (w, h) = self.info.image_size();
        let level = self.options.png;
        let mut images = EncodedImages::new();
        // Other features' images are stored as they came (no encoding).
        for feature in self
            .parquet_features
            .iter()
            .filter(|f| f.dtype == Dtype::Image && f.kind != FeatureKind::Other)
        {
            let kind = feature.kind;
            // Bytes the source stored in this encoding are copied (PNG and TIFF are lossless: the
            // pixels are the same whatever compression made them).
            if let Some(stored) = episode.stored_frames(&feature.name, ImageEncoding::of_kind(kind))
            {
                let bytes = stored.iter().map(|f| f.data.clone()).collect();
                images.insert(feature.name.clone(), bytes);
                continue;
            }
            let encode = |step: &crate::episode::Step| match kind {
                FeatureKind::Rgb => encode_png(w, h, 3, &step.rgb, level),
                FeatureKind::Mask => encode_png(w, h, 1, &step.mask, level),
                _ => Ok(encode_f32_tiff(w as u32, h as u32, &step.depth_m)),
            };
            let encoded: Result<Vec<Vec<u8>>, ExportError> = if self.parallel {
                episode.steps.par_iter().map(encode).collect()
            } else {
                episode.steps.iter().map(encode).collect()
            };
            images.insert(feature.name.clone(), encoded?);
        }
        Ok(images)
    }

    /// Statistics of the episode's features, in feature order: frames in parallel, folded in
    /// frame order (so the result does not depend on the thread count).
    pub fn feature_stats(&self, episode: &Episode) -> EpisodeStats {
        let features = &self.info.features;
        // A feature whose pixels are not in the steps (video) gets its statistics below.
        let kinds: Vec<Option<FeatureKind>> = features
            .iter()
            .map(|f| f.in_steps().then_some(f.kind))
            .collect();
        let mut total: EpisodeStats = features
            .iter()
            .map(|f| (f.name.clone(), FeatureStats::for_feature(f)))
            .collect();
        // Frames in chunks in parallel: each frame's statistics on their own (their sums are
        // folded in frame order below), its images' pixel counts into its chunk's histograms
        // (integers: any order).
        let chunk_stats = |chunk: &[crate::episode::Step]| {
            let mut histograms: Vec<Vec<Vec<u64>>> = total
                .iter()
                .map(|(_, s)| match s {
                    FeatureStats::Image(s) => s.empty_histograms(),
                    _ => Vec::new(),
                })
                .collect();
            let frames = chunk
                .iter()
                .map(|step| self.frame_stats(&total, &kinds, step, &mut histograms))
                .collect();
            (frames, histograms)
        };
        let chunks: Vec<ChunkStats> = if self.parallel {
            episode
                .steps
                .par_chunks(STATS_CHUNK_FRAMES)
                .map(chunk_stats)
                .collect()
        } else {
            episode
                .steps
                .chunks(STATS_CHUNK_FRAMES)
                .map(chunk_stats)
                .collect()
        };
        for (frames, histograms) in chunks {
            for frame in frames {
                for ((_, t), (_, f)) in total.iter_mut().zip(frame) {
                    t.merge(&f);
                }
            }
            for ((_, t), h) in total.iter_mut().zip(&histograms) {
                if let FeatureStats::Image(t) = t {
                    t.add_histograms(h);
                }
            }
        }
        for (feature, (_, t)) in features.iter().zip(total.iter_mut()) {
            if feature.in_steps() {
                continue;
            }
            // The RGB camera encoded here from its pixels had them in the steps; a copied video
            // brings its source's statistics.
            let carried = episode
                .encoded_video(&feature.name)
                .and_then(|e| e.pixel_stats.as_ref());
            match carried {
                Some(PixelStats::Exact(value)) => {
                    if let Ok(exact) = serde_json::from_value::<ImageStats>(value.clone()) {
                        *t = FeatureStats::Image(exact);
                    }
                }
                Some(PixelStats::Summary(value)) => {
                    if let Some(summary) = SummaryStats::from_json(value) {
                        *t = FeatureStats::Summary(summary);
                    }
                }
                None => {}
            }
        }
        total
    }

    /// One frame's statistics of the features, shaped as `shape` (the episode's), with its
    /// images' pixel counts added to `histograms` (per feature) instead of its own.
    fn frame_stats(
        &self,
        shape: &EpisodeStats,
        kinds: &[Option<FeatureKind>],
        step: &crate::episode::Step,
        histograms: &mut [Vec<Vec<u64>>],
    ) -> EpisodeStats {
        let mut stats: EpisodeStats = shape
            .iter()
            .map(|(name, s)| {
                let empty = match s {
                    FeatureStats::Image(s) => FeatureStats::Image(s.without_histograms()),
                    FeatureStats::Vector(s) => FeatureStats::Vector(VectorStats::new(s.elements())),
                    other => other.clone(),
                };
                (name.clone(), empty)
            })
            .collect();
        let mut others = step.other.iter();
        for (((_, s), counts), kind) in stats.iter_mut().zip(histograms).zip(kinds) {
            match (*kind, s) {
                (Some(FeatureKind::Rgb), FeatureStats::Image(s)) => {
                    s.push_u8_counting(&step.rgb, counts)
                }
                (Some(FeatureKind::Mask), FeatureStats::Image(s)) => {
                    s.push_u8_counting(&step.mask, counts)
                }
                (Some(FeatureKind::Depth), FeatureStats::Image(s)) => {
                    s.push_depth_counting(&step.depth_m, counts)
                }
                (Some(FeatureKind::State), FeatureStats::Vector(s)) => s.push(&step.state),
                (Some(FeatureKind::Action), FeatureStats::Vector(s)) => s.push(&step.action),
                (Some(FeatureKind::EnvironmentState), FeatureStats::Vector(s)) => {
                    s.push(&step.environment_state)
                }
                (Some(FeatureKind::Other), s) => match (others.next(), s) {
                    (Some(FeatureValue::Float32(v)), FeatureStats::Vector(s)) => s.push(v),
                    (Some(FeatureValue::Int64(v)), FeatureStats::Vector(s)) => {
                        s.push(&v.iter().map(|&x| x as f32).collect::<Vec<_>>())
                    }
                    (Some(FeatureValue::Image(bytes)), FeatureStats::Image(s)) => {
                        // Statistics need pixels: PNG decodes here; other encodings leave the
                        // image out of them.
                        if let Ok((_, _, _, pixels)) = decode_png(bytes) {
                            s.push_u8_counting(&pixels, counts)
                        }
                    }
                    _ => {}
                },
                _ => {}
            }
        }
        stats
    }
}

/// Statistics of the default columns (timestamp, frame, episode and dataset indices, task) of
/// an episode whose first frame is the dataset's `first_index`-th.
pub(super) fn default_stats(
    episode: &Episode,
    fps: f64,
    task_index: u64,
    first_index: u64,
) -> EpisodeStats {
    let mut stats: Vec<VectorStats> = DEFAULT_COLUMNS
        .iter()
        .map(|_| VectorStats::new(1))
        .collect();
    let episode_index = episode.meta.index as f64;
    for i in 0..episode.steps.len() {
        let values = [
            i as f64 / fps,
            i as f64,
            episode_index,
            (first_index + i as u64) as f64,
            task_index as f64,
        ];
        for (s, v) in stats.iter_mut().zip(values) {
            s.push(&[v as f32]);
        }
    }
    DEFAULT_COLUMNS
        .iter()
        .zip(stats)
        .map(|(name, s)| (name.to_string(), FeatureStats::Vector(s)))
        .collect()
}

/// A chunk of frames' statistics, each frame's own, and the pixel counts of the chunk's images
/// per feature (see [`EpisodeWork::feature_stats`]).
type ChunkStats = (Vec<EpisodeStats>, Vec<Vec<Vec<u64>>>);

/// Frames whose statistics one rayon task computes (and whose pixel counts share histograms).
const STATS_CHUNK_FRAMES: usize = 8;

/// One episode made ready to append.
pub struct Prepared {
    /// The video features' frames, in [`EpisodeWork::video_features`] order.
    pub video: Vec<Vec<EncodedFrame>>,
    /// The parquet's images, encoded ahead (by the detached encoder); `None`: at append.
    pub images: Option<EncodedImages>,
    /// The features' statistics ([`EpisodeWork::feature_stats`]), made ahead; `None`: at
    /// append.
    pub stats: Option<EpisodeStats>,
    /// Seconds the detached encoder spent on the images and on the statistics.
    pub encode_secs: f64,
    pub stats_secs: f64,
}

/// A batch's episodes encode their video features in parallel (one encoder per episode); their
/// images and statistics are made at append, frames in parallel.
impl crate::export::writer::EpisodeEncoder<Prepared> for EpisodeWork<'_> {
    fn encode(&self, episode: &Episode) -> Result<Prepared, ExportError> {
        Ok(Prepared {
            video: self.video_frames(episode)?,
            images: None,
            stats: None,
            encode_secs: 0.0,
            stats_secs: 0.0,
        })
    }
}

/// What [`EpisodeWork`] borrows, owned: the detached encoder, which makes everything but the
/// default columns' statistics (they need the episode's place in the dataset) on the
/// producer's threads while the writer appends earlier episodes.
pub struct OwnedWork {
    pub info: DatasetInfo,
    pub parquet_features: Vec<FeatureSpec>,
    pub video_features: Vec<(String, VideoCodec)>,
    pub options: LeRobotOptions,
}

impl OwnedWork {
    fn work(&self) -> EpisodeWork<'_> {
        EpisodeWork {
            parallel: false,
            info: &self.info,
            parquet_features: &self.parquet_features,
            video_features: &self.video_features,
            options: &self.options,
        }
    }
}

impl crate::export::writer::EpisodeEncoder<Prepared> for OwnedWork {
    fn encode(&self, episode: &Episode) -> Result<Prepared, ExportError> {
        let work = self.work();
        let started = std::time::Instant::now();
        let video = work.video_frames(episode)?;
        let images = work.encode_images(episode)?;
        let encoded = std::time::Instant::now();
        let stats = work.feature_stats(episode);
        Ok(Prepared {
            video,
            images: Some(images),
            stats: Some(stats),
            encode_secs: (encoded - started).as_secs_f64(),
            stats_secs: encoded.elapsed().as_secs_f64(),
        })
    }
}

/// Step `step`'s RGB pixels of the other feature at value `at` (a PNG of `width` x `height`).
fn other_rgb(
    step: &crate::episode::Step,
    at: usize,
    width: usize,
    height: usize,
    key: &str,
    index: usize,
) -> Result<Vec<u8>, ExportError> {
    let bad =
        |problem: String| ExportError::InvalidEpisode(format!("{key} step {index}: {problem}"));
    let Some(crate::episode::FeatureValue::Image(bytes)) = step.other.get(at) else {
        return Err(bad("holds no image".into()));
    };
    let (w, h, channels, pixels) =
        crate::export::image::decode_png_sized(bytes, Some((width, height))).map_err(bad)?;
    if (w as usize, h as usize, channels) != (width, height, 3) {
        return Err(bad(format!(
            "a {w}x{h} image with {channels} channels where {width}x{height} RGB was declared"
        )));
    }
    Ok(pixels)
}
