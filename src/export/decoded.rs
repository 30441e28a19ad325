//! A source whose video features arrive decoded: [`Decoded`] wraps any [`EpisodeSource`] and
//! turns each video feature's samples into pixels, the picture lerobot would give each row
//! (the reader picked them: [`crate::episode::EncodedFeature::shown`]). The camera of the RGB
//! role lands in the steps' `rgb`; another camera becomes a PNG-encoded image feature of its
//! own, so every format can write it.
//!
//! Episodes are decoded in batches of one per worker thread of the current rayon pool (one
//! episode per worker), so memory holds a few episodes whatever the dataset's length, and each
//! picture is converted to RGB as it leaves the decoder.

use crate::episode::{
    Dtype, EncodedFeature, Episode, FeatureKind, FeatureValue, ImageEncoding, PixelStats,
};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;
use crate::export::stats::ImageStats;
use crate::media::decode::{MAX_DECODED_SIDE_PX, YuvFrame, decode_span_each, rgb_from_yuv420};
use crate::media::image::{PngLevel, encode_png};
use rayon::prelude::*;
use std::collections::VecDeque;

/// Where a video feature's decoded frames go.
#[derive(Clone, Debug)]
struct Target {
    name: String,
    /// The frame size info.json declares (width, height).
    size_px: (usize, usize),
    /// The RGB role (the steps' `rgb`), or the index into the steps' `other` values.
    slot: Slot,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    Rgb,
    Other(usize),
}

/// [`EpisodeSource`] with video decoded to pixels.
pub struct Decoded {
    inner: Box<dyn EpisodeSource + Send>,
    info: DatasetInfo,
    targets: Vec<Target>,
    ready: VecDeque<Result<Episode, ExportError>>,
    /// Whether the inner source ended (or failed).
    drained: bool,
}

/// The (width, height) of an image feature's shape, channels last (LeRobot's
/// `[height, width, channels]`) or first (`[channels, height, width]`, older datasets).
fn frame_size(shape: &[usize]) -> Option<(usize, usize)> {
    match shape {
        [h, w, 3] => Some((*w, *h)),
        [3, h, w] => Some((*w, *h)),
        _ => None,
    }
}

impl Decoded {
    /// Wraps `inner`; its video features become image features. Depth or mask stored as
    /// video, and frames of no RGB shape, are the user's error (nothing surgvla decodes).
    pub fn new(inner: Box<dyn EpisodeSource + Send>) -> Result<Self, ExportError> {
        let mut info = inner.info().clone();
        let mut targets = Vec::new();
        let mut others = 0;
        for feature in &mut info.features {
            let video = feature.video.take();
            if video.is_some() {
                // The video's own settings describe the stream that is decoded here.
                feature
                    .info
                    .retain(|key, _| !key.starts_with("video.") && key != "is_depth_map");
                let size_px = frame_size(&feature.shape).ok_or_else(|| {
                    ExportError::InvalidOptions(format!(
                        "{} is video of shape {:?}; surgvla decodes 3-channel video only",
                        feature.name, feature.shape
                    ))
                })?;
                let slot = match feature.kind {
                    FeatureKind::Rgb => Slot::Rgb,
                    FeatureKind::Other => Slot::Other(others),
                    kind => {
                        return Err(ExportError::InvalidOptions(format!(
                            "{} ({kind:?}) is stored as video; surgvla decodes camera video only",
                            feature.name
                        )));
                    }
                };
                feature.dtype = Dtype::Image;
                targets.push(Target {
                    name: feature.name.clone(),
                    size_px,
                    slot,
                });
            }
            if feature.kind == FeatureKind::Other && feature.in_steps() {
                others += 1;
            }
        }
        Ok(Decoded {
            inner,
            info,
            targets,
            ready: VecDeque::new(),
            drained: false,
        })
    }

    /// Whether `info` has a feature stored as video.
    pub fn needed(info: &DatasetInfo) -> bool {
        info.features.iter().any(|f| f.video.is_some())
    }

    /// Reads the next batch of episodes and decodes them in parallel.
    fn refill(&mut self) {
        let wanted = rayon::current_num_threads().max(1);
        let mut batch = Vec::with_capacity(wanted);
        while batch.len() < wanted && !self.drained {
            match self.inner.next() {
                Some(Ok(episode)) => batch.push(Ok(episode)),
                Some(Err(error)) => {
                    self.drained = true;
                    batch.push(Err(error));
                    break;
                }
                None => self.drained = true,
            }
        }
        let targets = &self.targets;
        let decoded: Vec<Result<Episode, ExportError>> = batch
            .into_par_iter()
            .map(|episode| episode.and_then(|e| decode_episode(e, targets)))
            .collect();
        self.ready.extend(decoded);
    }
}
impl Iterator for Decoded {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.ready.is_empty() && !self.drained {
            self.refill();
        }
        self.ready.pop_front()
    }
}

impl EpisodeSource for Decoded {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        match self.ready.pop_front() {
            Some(episode) => Some(episode.map(|_| ())),
            None if self.drained => None,
            None => self.inner.skip_episode(),
        }
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.inner.drop_stored(unused);
    }
}

/// Replaces `episode`'s video samples with decoded pixels, each step getting the picture the
/// reader picked for it.
fn decode_episode(mut episode: Episode, targets: &[Target]) -> Result<Episode, ExportError> {
    let index = episode.meta.index;
    let steps = episode.steps.len();
    for target in targets {
        let position = episode
            .encoded
            .iter()
            .position(|e| e.feature == target.name && matches!(e.encoding, ImageEncoding::Video(_)))
            .ok_or_else(|| {
                ExportError::InvalidEpisode(format!(
                    "episode {index} has no video frames of {}",
                    target.name
                ))
            })?;
        let encoded = episode.encoded.remove(position);
        let rgb = decode_feature(&encoded, target, index, steps)?;
        for (step, pixels) in episode.steps.iter_mut().zip(rgb) {
            match target.slot {
                Slot::Rgb => step.rgb = pixels,
                Slot::Other(at) => {
                    let (width, height) = target.size_px;
                    let png = encode_png(width, height, 3, &pixels, PngLevel::Fast)?;
                    if at > step.other.len() {
                        return Err(ExportError::Internal(format!(
                            "{} belongs at value {at} of {}",
                            target.name,
                            step.other.len()
                        )));
                    }
                    step.other.insert(at, FeatureValue::Image(png));
                }
            }
        }
    }
    Ok(episode)
}

/// Exact pixel statistics of every video feature `episode` brings without them (another tool's
/// dataset: its metadata carries a summary only), from its decoded frames, one per step as
/// lerobot selects them; features of no 3-channel shape in `info` are left alone.
pub fn exact_video_stats(episode: &mut Episode, info: &DatasetInfo) -> Result<(), ExportError> {
    let index = episode.meta.index;
    let steps = episode.steps.len();
    for encoded in episode.encoded.iter_mut() {
        if !matches!(encoded.encoding, ImageEncoding::Video(_))
            || matches!(encoded.pixel_stats, Some(PixelStats::Exact(_)))
        {
            continue;
        }
        let Some(size_px) = info
            .features
            .iter()
            .find(|f| f.name == encoded.feature)
            .and_then(|f| frame_size(&f.shape))
        else {
            continue;
        };
        let target = Target {
            name: encoded.feature.clone(),
            size_px,
            slot: Slot::Rgb,
        };
        let mut stats = ImageStats::unit_scaled(3);
        for rgb in decode_feature(encoded, &target, index, steps)? {
            stats.push_u8(&rgb);
        }
        let text = serde_json::to_string(&stats)
            .map_err(|e| ExportError::Internal(format!("statistics: {e}")))?;
        encoded.pixel_stats = Some(PixelStats::Exact(text));
    }
    Ok(())
}

/// One video feature's RGB frames, one per step.
fn decode_feature(
    encoded: &EncodedFeature,
    target: &Target,
    index: u64,
    steps: usize,
) -> Result<Vec<Vec<u8>>, ExportError> {
    let ImageEncoding::Video(codec) = encoded.encoding else {
        return Err(ExportError::Internal(format!(
            "{} is not video",
            target.name
        )));
    };
    let file = encoded
        .file
        .as_ref()
        .map_or_else(|| "the input".to_string(), |f| f.display().to_string());
    let what = format!("{} of episode {index} in {file}", target.name);
    let bad = |problem: String| match &encoded.file {
        Some(path) => ExportError::InvalidDataset {
            path: path.clone(),
            problem,
        },
        None => ExportError::InvalidEpisode(problem),
    };
    let shown: Vec<usize> = match &encoded.shown {
        Some(shown) => shown.clone(),
        None => (0..encoded.frames.len()).collect(),
    };
    if shown.len() != steps {
        return Err(bad(format!(
            "{} frames of {} for episode {index}'s {steps} rows",
            shown.len(),
            target.name
        )));
    }
    // The steps each picture (in presentation order) goes to.
    let mut users: Vec<Vec<usize>> = vec![Vec::new(); encoded.frames.len()];
    for (step, picture) in shown.iter().enumerate() {
        users
            .get_mut(*picture)
            .ok_or_else(|| {
                bad(format!(
                    "row {step} of episode {index} wants picture {picture} of {}",
                    encoded.frames.len()
                ))
            })?
            .push(step);
    }
    let mut rgb: Vec<Vec<u8>> = vec![Vec::new(); steps];
    let mut next = 0;
    let mut place = |picture: YuvFrame| -> Result<(), ExportError> {
        let at = next;
        next += 1;
        let Some(wanting) = users.get(at).filter(|u| !u.is_empty()) else {
            return Ok(());
        };
        let (width, height) = target.size_px;
        if (picture.width_px as usize, picture.height_px as usize) != (width, height) {
            return Err(bad(format!(
                "frame {at} of episode {index} ({}) decodes to {}x{} where info.json declares {width}x{height}",
                target.name, picture.width_px, picture.height_px
            )));
        }
        let pixels = rgb_from_yuv420(&picture).ok_or_else(|| {
            bad(format!(
                "frame {at} of episode {index} has misshapen planes"
            ))
        })?;
        // Rows sharing a picture (a repeated timestamp) get copies; the last takes it.
        if let Some((last, others)) = wanting.split_last() {
            for step in others {
                rgb[*step].clone_from(&pixels);
            }
            rgb[*last] = pixels;
        }
        Ok(())
    };
    decode_span_each(
        codec,
        &encoded.frames,
        &what,
        MAX_DECODED_SIDE_PX,
        &mut place,
    )?;
    Ok(rgb)
}

/// Encodes again, in their own codec at `quality`, the video features of `episode` that
/// cannot be copied as they are ([`EncodedFeature::shown`]: an episode starting mid-GOP, frames
/// the rows skip): each is decoded to the picture every step shows and encoded from a keyframe,
/// with exact pixel statistics. Returns the features encoded again (none: nothing to do).
pub fn reencode_uncopyable(
    episode: &mut Episode,
    info: &DatasetInfo,
    quality: u32,
) -> Result<Vec<String>, ExportError> {
    let index = episode.meta.index;
    let steps = episode.steps.len();
    let mut done = Vec::new();
    for encoded in episode.encoded.iter_mut() {
        let ImageEncoding::Video(codec) = encoded.encoding else {
            continue;
        };
        if encoded.shown.is_none() {
            continue;
        }
        let size_px = (info.features.iter())
            .find(|f| f.name == encoded.feature)
            .and_then(|f| frame_size(&f.shape))
            .ok_or_else(|| {
                ExportError::InvalidOptions(format!(
                    "{} is video of no 3-channel shape; surgvla cannot encode it again",
                    encoded.feature
                ))
            })?;
        let target = Target {
            name: encoded.feature.clone(),
            size_px,
            slot: Slot::Rgb,
        };
        let rgb = decode_feature(encoded, &target, index, steps)?;
        let mut stats = ImageStats::unit_scaled(3);
        for frame in &rgb {
            stats.push_u8(frame);
        }
        let frames: Vec<&[u8]> = rgb.iter().map(Vec::as_slice).collect();
        let (width, height) = size_px;
        encoded.frames =
            crate::media::video::encode(codec, &frames, width, height, info.fps, quality)?;
        encoded.shown = None;
        encoded.pixel_stats = Some(PixelStats::Exact(
            serde_json::to_string(&stats)
                .map_err(|e| ExportError::Internal(format!("statistics: {e}")))?,
        ));
        done.push(encoded.feature.clone());
    }
    Ok(done)
}
