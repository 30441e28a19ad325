//! The per-episode work that needs only the dataset's features and options, so it runs on rayon
//! threads while the writer holds its non-shareable parquet state: image encoding (PNG, TIFF),
//! video encoding, and the episode's statistics.

use super::meta::FeatureStatsJson;
use super::options::LeRobotOptions;
use super::table::{DEFAULT_COLUMNS, EncodedImages, ImageColumn};
use crate::episode::{
    Dtype, Episode, FeatureKind, FeatureSpec, FeatureValue, ImageEncoding, PixelStats, Pixels,
    Step, VideoCodec,
};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::stats::{FeatureStats, ImageStats, LastFrame, SummaryStats, VectorStats};
use crate::media::image::{decode_8bit_sized, encode_png_into};
use crate::media::tiff::{encode_f32_tiff_into, f32_tiff_len};
use crate::media::video::{EncodedFrame, encode};
use rayon::prelude::*;

/// Statistics per feature, then per default column, in column order.
pub(super) type EpisodeStats = Vec<(String, FeatureStats)>;

/// An episode's statistics as its row of the episodes table records them, per feature: its
/// statistics object (none for text, which has none), and its exact pixel statistics where the
/// table keeps them.
pub(super) type RowStats = Vec<(Option<FeatureStatsJson>, Option<String>)>;

/// One feature's entry of [`RowStats`]: `stats` as the row records them, for a feature that is
/// text or not, whose exact pixel statistics the table keeps or not.
pub(super) fn row_entry(
    stats: &FeatureStats,
    text: bool,
    keeps_pixels: bool,
) -> (Option<FeatureStatsJson>, Option<String>) {
    let exact = keeps_pixels.then(|| match stats {
        FeatureStats::Image(s) => s.stored_json(),
        _ => "null".to_owned(),
    });
    let json = (!text).then(|| FeatureStatsJson::from_stated(&stats.stated()));
    (json, exact)
}

/// Whether the episodes table keeps feature `name`'s exact pixel statistics: a video feature,
/// or one of surgvla's images (RGB, depth, mask) in the parquet.
pub(super) fn keeps_pixel_stats(
    video_features: &[(String, VideoCodec)],
    parquet_features: &[FeatureSpec],
    name: &str,
) -> bool {
    video_features.iter().any(|(key, _)| key == name)
        || (parquet_features.iter())
            .any(|f| f.name == name && f.dtype == Dtype::Image && f.kind != FeatureKind::Other)
}

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

/// A video feature's frames as RGB pixels (borrowed from the steps, or decoded), and its
/// (width, height).
pub type VideoRgb<'e> = (Vec<std::borrow::Cow<'e, [u8]>>, (usize, usize));

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
                let (pixels, (width, height)) = self.video_rgb(episode, key)?;
                let frames: Vec<&[u8]> = pixels.iter().map(|p| p.as_ref()).collect();
                Ok(encode(*codec, &frames, width, height, self.info.fps, quality)?)
            })
            .collect()
    }

    /// Each step's RGB pixels of the video feature `key`, and the feature's (width, height):
    /// another dataset's camera decoded from its PNGs (they came from decoded video, or an
    /// image-mode dataset; frames in parallel), else the RGB camera's pixels.
    pub fn video_rgb<'e>(
        &self,
        episode: &'e Episode,
        key: &str,
    ) -> Result<VideoRgb<'e>, ExportError> {
        use std::borrow::Cow;
        let others = self
            .info
            .features
            .iter()
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps());
        if let Some((at, feature)) = others.enumerate().find(|(_, f)| f.name == *key) {
            let (height, width) = (feature.shape[0], feature.shape[1]);
            let pixels = (episode.steps.par_iter().enumerate())
                .map(|(i, step)| other_rgb(step, at, width, height, key, i).map(Cow::Owned))
                .collect::<Result<Vec<_>, ExportError>>()?;
            return Ok((pixels, (width, height)));
        }
        let pixels = (episode.steps.iter())
            .map(|s| Cow::Borrowed(s.rgb.as_slice()))
            .collect();
        Ok((pixels, self.info.image_size()))
    }

    /// Encodes every image stored in the parquet (frames in parallel, order kept).
    pub fn encode_images(&self, episode: &Episode) -> Result<EncodedImages, ExportError> {
        let mut images = EncodedImages::new();
        for (name, plan) in self.image_plans(episode)? {
            let encoded = match plan {
                ImagePlan::Stored(column) => column,
                ImagePlan::Encode(kind) if self.parallel => {
                    let frames: Vec<Vec<u8>> = episode
                        .steps
                        .par_iter()
                        .map(|step| {
                            let mut out = Vec::new();
                            self.encode_image(kind, step, &mut out)?;
                            Ok::<_, ExportError>(out)
                        })
                        .collect::<Result<_, _>>()?;
                    ImageColumn::from_frames(frames.iter().map(Vec::as_slice))?
                }
                ImagePlan::Encode(kind) => {
                    let mut column = self.image_column(kind, episode.steps.len());
                    for step in &episode.steps {
                        column.push_with(|out| self.encode_image(kind, step, out))?;
                    }
                    column
                }
            };
            images.insert(name, encoded);
        }
        Ok(images)
    }

    /// What becomes of each image feature stored in the parquet, by name: bytes the source
    /// stored in the feature's encoding are copied (PNG and TIFF are lossless: the pixels are
    /// the same whatever compression made them); other features' images are stored as they
    /// came (not here); images left in the source's stored rows are copied with them (not
    /// here either).
    fn image_plans(&self, episode: &Episode) -> Result<Vec<(String, ImagePlan)>, ExportError> {
        let elsewhere =
            |f: &FeatureSpec| (episode.stored_rows.as_ref()).is_some_and(|s| s.holds_pixels(f));
        self.parquet_features
            .iter()
            .filter(|f| f.dtype == Dtype::Image && f.kind != FeatureKind::Other && !elsewhere(f))
            .map(|feature| {
                let kind = feature.kind;
                let plan = match episode.stored_frames(&feature.name, ImageEncoding::of_kind(kind))
                {
                    Some(stored) => ImagePlan::Stored(ImageColumn::from_frames(
                        stored.iter().map(|f| f.data.as_slice()),
                    )?),
                    None => ImagePlan::Encode(kind),
                };
                Ok((feature.name.clone(), plan))
            })
            .collect()
    }

    /// Appends one step's image of a feature of `kind` to `out`: RGB and masks as PNG, depth
    /// as float TIFF.
    fn encode_image(
        &self,
        kind: FeatureKind,
        step: &Step,
        out: &mut Vec<u8>,
    ) -> Result<(), ExportError> {
        let (w, h) = self.info.image_size();
        match kind {
            FeatureKind::Rgb => Ok(encode_png_into(out, w, h, 3, &step.rgb, self.options.png)?),
            FeatureKind::Mask => Ok(encode_png_into(out, w, h, 1, &step.mask, self.options.png)?),
            _ => {
                encode_f32_tiff_into(out, w as u32, h as u32, &step.depth_m);
                Ok(())
            }
        }
    }

    /// An empty column for `frames` images of `kind`, sized for them: a depth TIFF's size is
    /// known; a PNG's is guessed (the buffer grows if needed).
    fn image_column(&self, kind: FeatureKind, frames: usize) -> ImageColumn {
        let (w, h) = self.info.image_size();
        let per_frame = match kind {
            FeatureKind::Depth => f32_tiff_len(w * h),
            _ => w * h,
        };
        ImageColumn::with_capacity(frames, per_frame)
    }

    /// [`EpisodeWork::encode_images`] and [`EpisodeWork::feature_stats`] on one thread, frame
    /// by frame (see [`FrameWork`]; the same bytes and statistics).
    pub fn encode_with_stats(&self, episode: &Episode) -> Result<Finished, ExportError> {
        let plans = self.image_plans(episode)?;
        let mut frames = FrameWork::new(self, plans, episode.steps.len(), Some(episode));
        for step in &episode.steps {
            frames.push(self, step)?;
        }
        Ok(frames.finish(self, episode))
    }

    /// Statistics of the episode's features, in feature order: frames in parallel, folded in
    /// frame order (so the result does not depend on the thread count).
    pub fn feature_stats(&self, episode: &Episode) -> EpisodeStats {
        let mut fold = StatsFold::new(self, Some(episode));
        if fold.counts_pixels() {
            fold_in_chunks(&episode.steps, &fold.kinds, &mut fold.total, self.parallel);
        } else {
            // No pixel counted: each frame's values pushed in frame order, the same sums and
            // samples as merging each frame's own statistics, without making them.
            for step in &episode.steps {
                fold.push(step);
            }
        }
        fold.finish(self, episode)
    }

    /// `stats` (an episode's, per feature) as its row of the episodes table records them.
    pub(super) fn row_stats(&self, stats: &EpisodeStats) -> RowStats {
        (stats.iter())
            .map(|(name, stats)| self.row_entry(name, stats))
            .collect()
    }

    /// Feature `name`'s entry of [`RowStats`].
    pub(super) fn row_entry(
        &self,
        name: &str,
        stats: &FeatureStats,
    ) -> (Option<FeatureStatsJson>, Option<String>) {
        let keeps_pixels = self.info.is_ours()
            && keeps_pixel_stats(self.video_features, self.parquet_features, name);
        row_entry(stats, self.info.is_text(name), keeps_pixels)
    }

    /// Each feature's kind when its values are in the steps; `None` for a feature whose pixels
    /// are not (video), which gets its statistics from [`EpisodeWork::carried_stats`].
    fn step_kinds(&self) -> Vec<Option<FeatureKind>> {
        self.info
            .features
            .iter()
            .map(|f| f.in_steps().then_some(f.kind))
            .collect()
    }

    /// The statistics of features whose pixels are not in the steps (video): the RGB camera
    /// encoded here from its pixels had them in the steps; a copied video brings its source's
    /// statistics. Images in the steps whose statistics the episode carries
    /// ([`Episode::image_stats`]) take them too.
    fn carried_stats(
        &self,
        episode: &Episode,
        carried: Vec<Option<ImageStats>>,
        total: &mut EpisodeStats,
    ) {
        let features = &self.info.features;
        // (None for every feature when the episode was not known ahead.)
        let carried = carried.into_iter().chain(std::iter::repeat_with(|| None));
        for ((feature, (_, t)), carried) in features.iter().zip(total.iter_mut()).zip(carried) {
            if feature.in_steps() {
                if let Some(exact) = carried {
                    *t = FeatureStats::Image(exact);
                }
                continue;
            }
            let carried = episode
                .encoded_video(&feature.name)
                .and_then(|e| e.pixel_stats.as_ref());
            match carried {
                Some(PixelStats::Exact(value)) => {
                    if let Some(exact) = ImageStats::carried(value) {
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
    }
}

/// Per feature of `stats`, the empty pixel-count histograms of its images (none for others).
fn empty_histograms(stats: &EpisodeStats) -> Vec<Vec<Vec<u64>>> {
    (stats.iter())
        .map(|(_, s)| match s {
            FeatureStats::Image(s) => s.empty_histograms(),
            _ => Vec::new(),
        })
        .collect()
}

/// Folds `steps` into `total` (per feature): frames in chunks (in parallel when `parallel`),
/// each frame's statistics on their own (their sums folded in frame order, so the result does
/// not depend on the thread count), its images' pixel counts into its chunk's histograms
/// (integers: any order).
fn fold_in_chunks(
    steps: &[Step],
    kinds: &[Option<FeatureKind>],
    total: &mut EpisodeStats,
    parallel: bool,
) {
    let shape = &*total;
    let chunk_stats = |chunk: &[Step]| {
        let mut histograms = empty_histograms(shape);
        let mut last = vec![LastFrame::default(); shape.len()];
        let frames = (chunk.iter())
            .map(|step| frame_stats(shape, kinds, step, &mut histograms, &mut last))
            .collect();
        (frames, histograms)
    };
    let chunks: Vec<ChunkStats> = if parallel {
        steps
            .par_chunks(STATS_CHUNK_FRAMES)
            .map(chunk_stats)
            .collect()
    } else {
        steps.chunks(STATS_CHUNK_FRAMES).map(chunk_stats).collect()
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
}

/// One frame's statistics of the features, shaped as `shape` (the episode's), with its
/// images' pixel counts added to `histograms` (per feature) instead of its own.
fn frame_stats(
    shape: &EpisodeStats,
    kinds: &[Option<FeatureKind>],
    step: &Step,
    histograms: &mut [Vec<Vec<u64>>],
    last: &mut [LastFrame],
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
    fold_frame(&mut stats, kinds, step, histograms, last);
    stats
}

/// Folds one frame into `stats` (per feature): each image's own sums merged in, its pixel
/// counts added to `histograms`; vectors pushed (the same as merging a one-frame part).
fn fold_frame(
    stats: &mut EpisodeStats,
    kinds: &[Option<FeatureKind>],
    step: &Step,
    histograms: &mut [Vec<Vec<u64>>],
    last: &mut [LastFrame],
) {
    let image = |s: &mut ImageStats, push: &mut dyn FnMut(&mut ImageStats)| {
        let mut frame = s.without_histograms();
        push(&mut frame);
        s.merge(&frame);
    };
    let mut others = step.other.iter();
    let features = stats.iter_mut().zip(histograms).zip(kinds).zip(last);
    for ((((_, s), counts), kind), last) in features {
        match (*kind, s) {
            (Some(FeatureKind::Rgb), FeatureStats::Image(s)) => image(s, &mut |f| {
                f.push_u8_counting_since(&step.rgb, counts, last)
            }),
            (Some(FeatureKind::Mask), FeatureStats::Image(s)) => image(s, &mut |f| {
                f.push_u8_counting_since(&step.mask, counts, last)
            }),
            (Some(FeatureKind::Depth), FeatureStats::Image(s)) => image(s, &mut |f| {
                f.push_depth_counting_since(&step.depth_m, counts, last)
            }),
            (Some(FeatureKind::State), FeatureStats::Vector(s)) => s.push(&step.state),
            (Some(FeatureKind::Action), FeatureStats::Vector(s)) => s.push(&step.action),
            (Some(FeatureKind::EnvironmentState), FeatureStats::Vector(s)) => {
                s.push(&step.environment_state)
            }
            (Some(FeatureKind::Other), s) => match (others.next(), s) {
                (Some(FeatureValue::Float32(v)), FeatureStats::Vector(s)) => s.push(v),
                (Some(FeatureValue::Float64(v)), FeatureStats::Vector(s)) => s.push_f64(v),
                (Some(FeatureValue::Int64(v)), FeatureStats::Vector(s)) => {
                    s.push(&v.iter().map(|&x| x as f32).collect::<Vec<_>>())
                }
                (Some(FeatureValue::Image(bytes)), FeatureStats::Image(s)) => {
                    // Statistics need pixels: PNG and JPEG decode here; other encodings
                    // (a 16-bit depth PNG) leave the image out of them.
                    if let Ok((_, _, _, pixels)) = decode_8bit_sized(bytes, None) {
                        image(s, &mut |f| f.push_u8_counting_since(&pixels, counts, last))
                    }
                }
                _ => {}
            },
            _ => {}
        }
    }
}

/// The exact statistics `episode` carries for its image feature `feature` in the steps, if
/// any, in the shape the feature's statistics have (a stored accumulator is the input's word:
/// one of another shape is left out, and the pixels counted instead).
fn carried_image_stats(episode: &Episode, feature: &FeatureSpec) -> Option<ImageStats> {
    let value = (episode.image_stats.iter()).find_map(|(n, stats)| match stats {
        PixelStats::Exact(value) if *n == feature.name => Some(value),
        _ => None,
    })?;
    let exact = ImageStats::carried(value)?;
    exact.fits(feature).then_some(exact)
}

/// Per feature, the exact statistics `episode` carries for its images in the steps, if any.
fn carried_all(features: &[FeatureSpec], episode: &Episode) -> Vec<Option<ImageStats>> {
    (features.iter())
        .map(|feature| {
            (feature.in_steps() && !episode.image_stats.is_empty())
                .then(|| carried_image_stats(episode, feature))
                .flatten()
        })
        .collect()
}

/// How one image feature stored in the parquet gets its bytes.
enum ImagePlan {
    /// The source's own bytes, copied once into the feature's column.
    Stored(ImageColumn),
    /// Encoded here from the steps' pixels.
    Encode(FeatureKind),
}

/// An episode's images and statistics as [`FrameWork`] leaves them, with the seconds spent
/// encoding and on the statistics.
pub struct Finished {
    pub images: EncodedImages,
    pub stats: EpisodeStats,
    pub encode_secs: f64,
    pub stats_secs: f64,
}

/// One episode's images encoded and statistics taken frame by frame on one thread: each
/// frame's images one after the other, then its statistics, while its pixels are in the
/// core's cache.
pub struct FrameWork {
    /// Per image feature: its name, the kind encoded here (`None`: the source's bytes, already
    /// in its column) and its column.
    features: Vec<(String, Option<FeatureKind>, ImageColumn)>,
    fold: StatsFold,
    encode_secs: f64,
    stats_secs: f64,
}

impl FrameWork {
    /// For an episode of about `frames` frames (the columns' room); `episode` when it is
    /// known ahead, for the statistics it carries.
    fn new(
        work: &EpisodeWork<'_>,
        plans: Vec<(String, ImagePlan)>,
        frames: usize,
        episode: Option<&Episode>,
    ) -> Self {
        let features = plans
            .into_iter()
            .map(|(name, plan)| match plan {
                ImagePlan::Stored(column) => (name, None, column),
                ImagePlan::Encode(kind) => (name, Some(kind), work.image_column(kind, frames)),
            })
            .collect();
        FrameWork {
            features,
            fold: StatsFold::new(work, episode),
            encode_secs: 0.0,
            stats_secs: 0.0,
        }
    }

    fn push(&mut self, work: &EpisodeWork<'_>, step: &Step) -> Result<(), ExportError> {
        let started = std::time::Instant::now();
        for (_, kind, column) in &mut self.features {
            if let Some(kind) = *kind {
                column.push_with(|out| work.encode_image(kind, step, out))?;
            }
        }
        let encoded = std::time::Instant::now();
        self.fold.push(step);
        self.encode_secs += (encoded - started).as_secs_f64();
        self.stats_secs += encoded.elapsed().as_secs_f64();
        Ok(())
    }

    fn finish(self, work: &EpisodeWork<'_>, episode: &Episode) -> Finished {
        let started = std::time::Instant::now();
        let stats = self.fold.finish(work, episode);
        Finished {
            images: self
                .features
                .into_iter()
                .map(|(name, _, column)| (name, column))
                .collect(),
            stats,
            encode_secs: self.encode_secs,
            stats_secs: self.stats_secs + started.elapsed().as_secs_f64(),
        }
    }
}

/// The episode being appended part by part.
pub(super) struct OpenEpisode {
    pub(super) index: u64,
    /// The dataset index of its first frame.
    pub(super) first_index: u64,
    /// Its steps' task indices so far (one per step appended).
    pub(super) task_indices: Vec<u64>,
    pub(super) fold: StatsFold,
    /// Per video feature, its encoder, and where the episode starts in its file (seconds).
    pub(super) encoders: Vec<crate::media::video::VideoEncoder>,
    pub(super) video_from: Vec<f64>,
}

impl OpenEpisode {
    /// The episode's index.
    pub(super) fn index(&self) -> u64 {
        self.index
    }
}

/// An episode's feature statistics taken frame by frame on one thread: each frame's sums
/// folded into the episode's in frame order, its pixel counts into one set of histograms (as
/// [`EpisodeWork::feature_stats`] does in chunks).
pub(super) struct StatsFold {
    kinds: Vec<Option<FeatureKind>>,
    total: EpisodeStats,
    /// Per feature, the pixel counts of its images (empty until a frame is pushed).
    histograms: Vec<Vec<Vec<u64>>>,
    /// Per feature, the last frame's pixels and counts.
    last: Vec<LastFrame>,
    /// The exact image statistics the episode known ahead carries (per feature), read once:
    /// left out of the fold, put in at [`StatsFold::finish`].
    carried: Option<Vec<Option<ImageStats>>>,
}

impl StatsFold {
    /// For `work`'s features; `episode` when it is known ahead, for the statistics it
    /// carries.
    pub(super) fn new(work: &EpisodeWork<'_>, episode: Option<&Episode>) -> Self {
        let features = &work.info.features;
        let carried = episode.map(|episode| carried_all(features, episode));
        // The images whose statistics the episode carries are left out of the frame-by-frame
        // statistics (no image decoded): [`EpisodeWork::carried_stats`] puts them in afterwards.
        let mut total: EpisodeStats = (features.iter().enumerate())
            .map(|(i, f)| match carried.as_ref().and_then(|c| c.get(i)) {
                Some(Some(_)) => (f.name.clone(), FeatureStats::Vector(VectorStats::new(0))),
                _ => (f.name.clone(), FeatureStats::for_feature(f)),
            })
            .collect();
        for (_, stats) in &mut total {
            if let (FeatureStats::Vector(stats), Some(episode)) = (stats, episode) {
                stats.reserve(episode.steps.len());
            }
        }
        StatsFold::of(work.step_kinds(), total, carried)
    }

    /// Folding into `total` (per feature, `kinds` their place in the steps).
    fn of(
        kinds: Vec<Option<FeatureKind>>,
        total: EpisodeStats,
        carried: Option<Vec<Option<ImageStats>>>,
    ) -> Self {
        StatsFold {
            kinds,
            last: vec![LastFrame::default(); total.len()],
            total,
            histograms: Vec::new(),
            carried,
        }
    }

    /// Whether a frame's pixels are counted (an image in the steps whose statistics the
    /// episode does not carry).
    fn counts_pixels(&self) -> bool {
        (self.total.iter().zip(&self.kinds))
            .any(|((_, s), kind)| kind.is_some() && matches!(s, FeatureStats::Image(_)))
    }

    pub(super) fn push(&mut self, step: &Step) {
        // (Made at the first frame: a fold whose frames are counted in chunks has none.)
        if self.histograms.is_empty() {
            self.histograms = empty_histograms(&self.total);
        }
        fold_frame(
            &mut self.total,
            &self.kinds,
            step,
            &mut self.histograms,
            &mut self.last,
        );
    }

    /// The episode's statistics: the folded frames', and those `episode` carries (the
    /// episode known ahead's, read when the fold began).
    pub(super) fn finish(mut self, work: &EpisodeWork<'_>, episode: &Episode) -> EpisodeStats {
        let carried =
            (self.carried.take()).unwrap_or_else(|| carried_all(&work.info.features, episode));
        self.finish_with(work, episode, carried)
    }

    /// [`StatsFold::finish`] for an episode that carries its statistics at its end (a
    /// recording's last part: the whole episode's), read again from `at_end`.
    pub(super) fn finish_at_end(self, work: &EpisodeWork<'_>, at_end: &Episode) -> EpisodeStats {
        let carried = carried_all(&work.info.features, at_end);
        self.finish_with(work, at_end, carried)
    }

    fn finish_with(
        mut self,
        work: &EpisodeWork<'_>,
        episode: &Episode,
        carried: Vec<Option<ImageStats>>,
    ) -> EpisodeStats {
        for ((_, t), h) in self.total.iter_mut().zip(&self.histograms) {
            if let FeatureStats::Image(t) = t {
                t.add_histograms(h);
            }
        }
        work.carried_stats(episode, carried, &mut self.total);
        self.total
    }
}

/// Statistics of the default columns (timestamp, frame, episode and dataset indices, task) of
/// episode `episode_index`, whose first frame is the dataset's `first_index`-th, its steps'
/// task indices `task_indices` (one per step).
pub(super) fn default_stats(
    episode_index: u64,
    fps: f64,
    task_indices: &[u64],
    first_index: u64,
) -> EpisodeStats {
    let mut stats: Vec<VectorStats> = DEFAULT_COLUMNS
        .iter()
        .map(|_| VectorStats::new(1))
        .collect();
    let episode_index = episode_index as f64;
    for (i, &task_index) in task_indices.iter().enumerate() {
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
    /// Those statistics as the episode's row records them ([`EpisodeWork::row_stats`]), made
    /// with them.
    pub row_stats: Option<RowStats>,
    /// Seconds the detached encoder spent on the images and on the statistics.
    pub encode_secs: f64,
    pub stats_secs: f64,
}

/// A batch's episodes encode their video features in parallel (one encoder per episode); their
/// images and statistics are made at append, frames in parallel. An episode whose rows are
/// copied as stored has nothing to encode, and its statistics (no pixel counted) are made here,
/// with the batch's others, instead of on the appending thread.
impl crate::export::writer::EpisodeEncoder<Prepared> for EpisodeWork<'_> {
    fn encode(&self, episode: &Episode) -> Result<Prepared, ExportError> {
        let stats = (episode.stored_rows.is_some()).then(|| self.feature_stats(episode));
        Ok(Prepared {
            video: self.video_frames(episode)?,
            images: None,
            row_stats: stats.as_ref().map(|s| self.row_stats(s)),
            stats,
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

/// [`OwnedWork`] shared with the frame-by-frame encoders it starts: the LeRobot sink's
/// detached encoder.
pub struct SharedWork(pub std::sync::Arc<OwnedWork>);

impl crate::export::writer::EpisodeEncoder<Prepared> for SharedWork {
    fn encode(&self, episode: &Episode) -> Result<Prepared, ExportError> {
        let work = self.0.work();
        if episode.stored_rows.is_some() {
            // Rows copied as stored: nothing to encode but the statistics, as in a batch.
            return work.encode(episode);
        }
        let started = std::time::Instant::now();
        let video = work.video_frames(episode)?;
        let video_secs = started.elapsed().as_secs_f64();
        let finished = work.encode_with_stats(episode)?;
        Ok(Prepared {
            video,
            images: Some(finished.images),
            row_stats: Some(work.row_stats(&finished.stats)),
            stats: Some(finished.stats),
            encode_secs: video_secs + finished.encode_secs,
            stats_secs: finished.stats_secs,
        })
    }

    /// Image mode only: a video feature is encoded from the whole episode's frames.
    fn frames(
        &self,
        expected_frames: usize,
    ) -> Option<Box<dyn crate::export::writer::EpisodeFrames<Prepared>>> {
        if !self.0.video_features.is_empty() {
            return None;
        }
        let work = self.0.work();
        // A recorded episode brings no stored images: every image feature is encoded.
        let plans = work
            .parquet_features
            .iter()
            .filter(|f| f.dtype == Dtype::Image && f.kind != FeatureKind::Other)
            .map(|f| (f.name.clone(), ImagePlan::Encode(f.kind)))
            .collect();
        let frames = FrameWork::new(&work, plans, expected_frames, None);
        Some(Box::new(FrameStream {
            owned: self.0.clone(),
            frames,
            pending: Vec::with_capacity(STREAM_BATCH_FRAMES),
            pushed: 0,
        }))
    }
}

/// Frames a [`FrameStream`] gathers before it encodes them one after another: encoding frame
/// by frame between the physics and the rendering of the next one was slower (each stage's
/// code and data pushed the others' out of the core's caches).
const STREAM_BATCH_FRAMES: usize = 64;

/// The LeRobot sink's frame-by-frame encoder (see [`crate::export::sink::FrameEncoder`]): it takes
/// each step's pixels as it is recorded and encodes them in batches of
/// [`STREAM_BATCH_FRAMES`], handing the buffers back to be drawn into again.
struct FrameStream {
    owned: std::sync::Arc<OwnedWork>,
    frames: FrameWork,
    /// Steps taken and not encoded yet: their pixels and what their statistics read.
    pending: Vec<Step>,
    pushed: usize,
}

impl FrameStream {
    /// Encodes the pending steps; returns their buffers.
    fn flush(&mut self) -> Result<Vec<Pixels>, ExportError> {
        let work = self.owned.work();
        let mut done = Vec::with_capacity(self.pending.len());
        for mut step in self.pending.drain(..) {
            self.frames.push(&work, &step)?;
            done.push(step.take_pixels());
        }
        Ok(done)
    }
}

impl crate::export::writer::EpisodeFrames<Prepared> for FrameStream {
    fn push(&mut self, step: &mut Step) -> Result<Vec<Pixels>, ExportError> {
        let work = self.owned.work();
        let (width, height) = work.info.image_size();
        crate::episode::step_pixels_fit(step, width, height, &work.info.features).map_err(
            |problem| ExportError::InvalidEpisode(format!("step {}: {problem}", self.pushed)),
        )?;
        let Pixels { rgb, depth_m, mask } = step.take_pixels();
        // What the statistics read besides the pixels (not the extras).
        self.pending.push(Step {
            rgb,
            depth_m,
            mask,
            state: step.state,
            action: step.action,
            environment_state: step.environment_state,
            other: step.other.clone(),
            ..Step::empty()
        });
        self.pushed += 1;
        if self.pending.len() < STREAM_BATCH_FRAMES {
            return Ok(Vec::new());
        }
        self.flush()
    }

    fn finish(mut self: Box<Self>, episode: &Episode) -> Result<Prepared, ExportError> {
        self.flush()?;
        if episode.steps.len() != self.pushed {
            return Err(ExportError::Internal(format!(
                "episode {}: {} frames encoded for {} steps",
                episode.meta.index,
                self.pushed,
                episode.steps.len()
            )));
        }
        let work = self.owned.work();
        let finished = self.frames.finish(&work, episode);
        Ok(Prepared {
            video: Vec::new(),
            images: Some(finished.images),
            row_stats: Some(work.row_stats(&finished.stats)),
            stats: Some(finished.stats),
            encode_secs: finished.encode_secs,
            stats_secs: finished.stats_secs,
        })
    }
}

/// Step `step`'s RGB pixels of the other feature at value `at` (a PNG of `width` x `height`).
fn other_rgb(
    step: &Step,
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
        crate::media::image::decode_8bit_sized(bytes, Some((width, height))).map_err(bad)?;
    if (w as usize, h as usize, channels) != (width, height, 3) {
        return Err(bad(format!(
            "a {w}x{h} image with {channels} channels where {width}x{height} RGB was declared"
        )));
    }
    Ok(pixels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// Folding frames straight into the totals gives the statistics that merging each frame's
    /// own gives, bit for bit (sums, extremes, the reservoir's samples), past the reservoir's
    /// size.
    #[test]
    fn frames_folded_in_order_equal_frames_merged_in_chunks() {
        let mut rng = SplitMix64::new(11);
        let mut value = move || (rng.next_u64() % 20_000) as f32 / 7.0 - 1_000.0;
        let kinds = [
            Some(FeatureKind::State),
            Some(FeatureKind::Action),
            Some(FeatureKind::Other),
            Some(FeatureKind::Other),
        ];
        let fresh = || -> EpisodeStats {
            [("state", 7), ("action", 7), ("f64", 2), ("i64", 3)]
                .into_iter()
                .map(|(n, k)| (n.to_string(), FeatureStats::Vector(VectorStats::new(k))))
                .collect()
        };
        let steps: Vec<Step> = (0..crate::export::stats::RESERVOIR + 300)
            .map(|_| Step {
                state: std::array::from_fn(|_| value()),
                action: std::array::from_fn(|_| value()),
                other: vec![
                    FeatureValue::Float64(vec![f64::from(value()) / 3.0, f64::from(value())]),
                    FeatureValue::Int64((0..3).map(|_| value() as i64).collect()),
                ],
                ..Step::empty()
            })
            .collect();
        let (mut in_chunks, mut in_parallel) = (fresh(), fresh());
        let mut fold = StatsFold::of(kinds.to_vec(), fresh(), None);
        assert!(!fold.counts_pixels());
        for step in &steps {
            fold.push(step);
        }
        let in_order = fold.total;
        fold_in_chunks(&steps, &kinds, &mut in_chunks, false);
        fold_in_chunks(&steps, &kinds, &mut in_parallel, true);
        let json = |stats: &EpisodeStats| -> Vec<String> {
            stats.iter().map(|(_, s)| s.to_json().to_string()).collect()
        };
        assert_eq!(json(&in_order), json(&in_chunks));
        assert_eq!(json(&in_order), json(&in_parallel));
        assert!(json(&in_order)[0].contains(&format!("\"count\":[{}]", steps.len())));
    }
}
