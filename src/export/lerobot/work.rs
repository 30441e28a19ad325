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
use crate::export::stats::{FeatureStats, ImageStats, SummaryStats};
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
            let encoded: Result<Vec<Vec<u8>>, ExportError> = episode
                .steps
                .par_iter()
                .map(|step| match kind {
                    FeatureKind::Rgb => encode_png(w, h, 3, &step.rgb, level),
                    FeatureKind::Mask => encode_png(w, h, 1, &step.mask, level),
                    _ => Ok(encode_f32_tiff(w as u32, h as u32, &step.depth_m)),
                })
                .collect();
            images.insert(feature.name.clone(), encoded?);
        }
        Ok(images)
    }

    /// Statistics of one episode: frames in parallel, folded in frame order (so the result does
    /// not depend on the thread count).
    pub fn episode_stats(
        &self,
        episode: &Episode,
        task_index: u64,
        first_index: u64,
    ) -> EpisodeStats {
        let features = &self.info.features;
        // A feature whose pixels are not in the steps (video) gets its statistics below.
        let kinds: Vec<Option<FeatureKind>> = features
            .iter()
            .map(|f| f.in_steps().then_some(f.kind))
            .collect();
        let fps = f64::from(self.info.fps);
        let episode_index = episode.meta.index as f64;
        let per_frame: Vec<EpisodeStats> = episode
            .steps
            .par_iter()
            .enumerate()
            .map(|(i, step)| {
                let mut stats = fresh_stats(features);
                let defaults = [
                    i as f64 / fps,
                    i as f64,
                    episode_index,
                    (first_index + i as u64) as f64,
                    task_index as f64,
                ];
                let mut default_values = defaults.iter();
                let mut others = step.other.iter();
                for (position, (_, s)) in stats.iter_mut().enumerate() {
                    if position < kinds.len() && kinds[position].is_none() {
                        continue;
                    }
                    let kind = kinds.get(position).copied().flatten();
                    match (kind, s) {
                        (Some(FeatureKind::Rgb), FeatureStats::Image(s)) => s.push_u8(&step.rgb),
                        (Some(FeatureKind::Mask), FeatureStats::Image(s)) => s.push_u8(&step.mask),
                        (Some(FeatureKind::Depth), FeatureStats::Image(s)) => {
                            s.push_depth(&step.depth_m)
                        }
                        (Some(FeatureKind::State), FeatureStats::Vector(s)) => s.push(&step.state),
                        (Some(FeatureKind::Action), FeatureStats::Vector(s)) => {
                            s.push(&step.action)
                        }
                        (Some(FeatureKind::EnvironmentState), FeatureStats::Vector(s)) => {
                            s.push(&step.environment_state)
                        }
                        (Some(FeatureKind::Other), s) => match (others.next(), s) {
                            (Some(FeatureValue::Float32(v)), FeatureStats::Vector(s)) => s.push(v),
                            (Some(FeatureValue::Int64(v)), FeatureStats::Vector(s)) => {
                                s.push(&v.iter().map(|&x| x as f32).collect::<Vec<_>>())
                            }
                            (Some(FeatureValue::Image(bytes)), FeatureStats::Image(s)) => {
                                // Statistics need pixels: PNG decodes here; other encodings
                                // leave the image out of them.
                                if let Ok((_, _, _, pixels)) = decode_png(bytes) {
                                    s.push_u8(&pixels)
                                }
                            }
                            _ => {}
                        },
                        (None, FeatureStats::Vector(s)) => {
                            s.push(&[default_values.next().copied().unwrap_or(0.0) as f32])
                        }
                        _ => {}
                    }
                }
                stats
            })
            .collect();
        let mut total = fresh_stats(features);
        for frame in per_frame {
            for ((_, t), (_, f)) in total.iter_mut().zip(frame) {
                t.merge(&f);
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
}

/// A batch's episodes encode their video features in parallel (one encoder per episode).
impl crate::export::writer::EpisodeEncoder<Vec<Vec<EncodedFrame>>> for EpisodeWork<'_> {
    fn encode(&self, episode: &Episode) -> Result<Vec<Vec<EncodedFrame>>, ExportError> {
        self.video_frames(episode)
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
