//! Converting a dataset: every episode of an [`EpisodeSource`] into an [`EpisodeSink`] made
//! with the source's [`DatasetInfo`](crate::export::DatasetInfo). Episodes travel in small
//! batches (one per worker thread, so the sink encodes them in parallel and memory stays
//! bounded by a few episodes); a resumed sink skips the episodes it already holds.

use crate::episode::{Episode, FeatureKind, MAX_OBJECTS, POSE_VALUES};
use crate::error::ErrorKind;
use crate::export::{EpisodeSink, EpisodeSource, ExportError, Summary};

/// Which side of a conversion failed.
#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
    /// The input dataset is unreadable or invalid (resuming will not help until it is
    /// repaired).
    #[error("reading the input dataset")]
    Read(#[source] ExportError),
    /// Writing the output failed (a full disk: resume once there is space).
    #[error("writing the output dataset")]
    Write(#[source] ExportError),
}

impl crate::error::HasKind for ConvertError {
    fn kind(&self) -> ErrorKind {
        match self {
            ConvertError::Read(error) | ConvertError::Write(error) => error.kind(),
        }
    }

    /// Whether the output's disk (or quota) is full.
    fn is_disk_full(&self) -> bool {
        matches!(self, ConvertError::Write(error) if error.is_disk_full())
    }
}

/// Copies every episode of `source` into `sink` on `threads` worker threads (0: one per core)
/// and finishes it; `progress` is told the number of episodes done after each batch.
pub fn convert(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    threads: usize,
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<Summary, ConvertError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| {
            ConvertError::Write(ExportError::Internal(format!("no worker threads: {e}")))
        })?;
    pool.install(|| copy(source, sink, progress))
}

fn copy(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<Summary, ConvertError> {
    let skip = sink.next_episode_index();
    let batch_size = rayon::current_num_threads().max(1);
    let mut batch = Vec::with_capacity(batch_size);
    let mut done = 0u64;
    while let Some(episode) = source.next_episode() {
        let episode = episode.map_err(ConvertError::Read)?;
        done += 1;
        if episode.meta.index < skip {
            continue;
        }
        batch.push(episode);
        if batch.len() == batch_size {
            sink.write_batch(&batch).map_err(ConvertError::Write)?;
            batch.clear();
            progress(done);
        }
    }
    if !batch.is_empty() {
        sink.write_batch(&batch).map_err(ConvertError::Write)?;
    }
    progress(done);
    sink.finish().map_err(ConvertError::Write)
}

/// A source with some optional features left out (`convert --without`): they leave the
/// dataset's features and every step.
pub struct Without {
    inner: Box<dyn EpisodeSource + Send>,
    info: crate::export::DatasetInfo,
    kinds: Vec<FeatureKind>,
}

impl Without {
    /// `inner` without the features of `kinds` (RGB, state and action cannot be left out: they
    /// are ignored here).
    pub fn new(inner: Box<dyn EpisodeSource + Send>, kinds: &[FeatureKind]) -> Self {
        let kinds: Vec<FeatureKind> = kinds
            .iter()
            .copied()
            .filter(|k| {
                matches!(
                    k,
                    FeatureKind::Depth | FeatureKind::Mask | FeatureKind::EnvironmentState
                )
            })
            .collect();
        let mut info = inner.info().clone();
        info.features.retain(|f| !kinds.contains(&f.kind));
        Without { inner, info, kinds }
    }

    fn strip(&self, mut episode: Episode) -> Episode {
        let kept = &self.info.features;
        episode
            .encoded
            .retain(|e| kept.iter().any(|f| f.name == e.feature));
        for step in &mut episode.steps {
            for kind in &self.kinds {
                match kind {
                    FeatureKind::Depth => step.depth_m = Vec::new(),
                    FeatureKind::Mask => step.mask = Vec::new(),
                    FeatureKind::EnvironmentState => {
                        step.environment_state = [0.0; MAX_OBJECTS * POSE_VALUES]
                    }
                    _ => {}
                }
            }
        }
        episode
    }
}

impl EpisodeSource for Without {
    fn info(&self) -> &crate::export::DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn next_episode(&mut self) -> Option<Result<Episode, ExportError>> {
        let episode = self.inner.next_episode()?;
        Some(episode.map(|e| self.strip(e)))
    }
}

/// Depth may differ by this much between a source and a target that stores millimetres (RLDS):
/// half a millimetre of rounding, plus float slack.
pub const DEPTH_TOLERANCE_M: f32 = 0.000_51;

/// Whether a video feature both episodes hold as video differs in any frame's bytes (video
/// is copied, never re-encoded, so the bytes must be the same).
fn video_differs(a: &Episode, b: &Episode) -> bool {
    a.encoded
        .iter()
        .filter(|e| matches!(e.encoding, crate::episode::ImageEncoding::Video(_)))
        .any(|x| {
            b.encoded_video(&x.feature)
                .is_some_and(|y| y.encoding != x.encoding || y.frames != x.frames)
        })
}

/// Whether two steps' other features (by name) differ: images within `tolerance` (their
/// decoded pixels' [`mean_abs_difference`]) when given, everything else exactly.
fn others_differ(
    a: &std::collections::BTreeMap<String, crate::episode::FeatureValue>,
    b: &std::collections::BTreeMap<String, crate::episode::FeatureValue>,
    tolerance: Option<f64>,
) -> bool {
    use crate::episode::FeatureValue;
    let Some(tolerance) = tolerance else {
        return a != b;
    };
    let pixels = |bytes: &[u8]| crate::export::image::decode_png(bytes).ok().map(|p| p.3);
    a.len() != b.len()
        || a.iter().any(|(name, x)| match (x, b.get(name)) {
            (FeatureValue::Image(x), Some(FeatureValue::Image(y))) => {
                match (pixels(x), pixels(y)) {
                    (Some(p), Some(q)) => mean_abs_difference(&p, &q) > tolerance,
                    _ => true,
                }
            }
            (x, y) => Some(x) != y,
        })
}

/// What `convert --verify` found: episodes and frames compared, and the first differences.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Verification {
    pub episodes: u64,
    pub frames: u64,
    /// Each difference: where and what (empty: the target holds the source's data).
    pub differences: Vec<String>,
}

/// Reads `source` and `target` (opened again after a conversion) side by side and compares
/// every episode and frame: instruction and provenance, RGB and mask pixel for pixel, state,
/// action and object poses bit for bit, depth exactly (to 0.5 mm when the target stores
/// millimetres), other datasets' features value for value (images byte for byte). Only
/// features both sides hold are compared.
pub fn verify(
    source: &mut dyn EpisodeSource,
    target: &mut dyn EpisodeSource,
) -> Result<Verification, ConvertError> {
    verify_within(source, target, None)
}

/// The largest mean absolute difference, in 8-bit levels over a frame's bytes, between an RGB
/// frame and its lossy re-encoding that `--verify` accepts (AV1 and H.264 at surgvla's
/// settings stay near 1-2 levels on the benchmark's frames; a wrong or shifted frame is tens).
pub const LOSSY_RGB_MEAN_TOLERANCE: f64 = 6.0;

/// The mean absolute difference of two equally long byte images (infinite when their
/// lengths differ).
pub fn mean_abs_difference(a: &[u8], b: &[u8]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    let sum: u64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| u64::from(x.abs_diff(*y)))
        .sum();
    sum as f64 / a.len().max(1) as f64
}

/// [`verify`], RGB compared within `rgb_mean_tolerance` ([`mean_abs_difference`] per frame)
/// when the target stores it lossily, exactly when None.
pub fn verify_within(
    source: &mut dyn EpisodeSource,
    target: &mut dyn EpisodeSource,
    rgb_mean_tolerance: Option<f64>,
) -> Result<Verification, ConvertError> {
    let rgb_differs = |x: &[u8], y: &[u8]| match rgb_mean_tolerance {
        None => x != y,
        Some(tolerance) => mean_abs_difference(x, y) > tolerance,
    };
    let mut result = Verification::default();
    let has = |info: &crate::export::DatasetInfo, kind| info.has(kind);
    let (a_info, b_info) = (source.info().clone(), target.info().clone());
    let both = |kind| has(&a_info, kind) && has(&b_info, kind);
    // Other features by name: formats may order them differently.
    let others = |info: &crate::export::DatasetInfo| -> Vec<String> {
        info.features
            .iter()
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
            .map(|f| f.name.clone())
            .collect()
    };
    let (a_others, b_others) = (others(&a_info), others(&b_info));
    let named = |names: &[String], values: &[crate::episode::FeatureValue]| {
        names
            .iter()
            .cloned()
            .zip(values.iter().cloned())
            .collect::<std::collections::BTreeMap<_, _>>()
    };
    let note = |result: &mut Verification, text: String| {
        if result.differences.len() < 20 {
            result.differences.push(text);
        }
    };
    loop {
        let (a, b) = (source.next_episode(), target.next_episode());
        let (a, b) = match (a, b) {
            (None, None) => return Ok(result),
            (Some(a), Some(b)) => (
                a.map_err(ConvertError::Read)?,
                b.map_err(ConvertError::Write)?,
            ),
            (Some(_), None) => {
                let text = format!(
                    "the output lacks episode {} and later ones",
                    result.episodes
                );
                note(&mut result, text);
                return Ok(result);
            }
            (None, Some(_)) => {
                let text = format!(
                    "the output has more than the input's {} episodes",
                    result.episodes
                );
                note(&mut result, text);
                return Ok(result);
            }
        };
        let index = a.meta.index;
        result.episodes += 1;
        result.frames += a.steps.len() as u64;
        if a.meta.instruction != b.meta.instruction {
            note(
                &mut result,
                format!(
                    "episode {index}: instruction {:?} became {:?}",
                    a.meta.instruction, b.meta.instruction
                ),
            );
        }
        if (a.meta.seed, &a.meta.task_code) != (b.meta.seed, &b.meta.task_code) {
            note(
                &mut result,
                format!("episode {index}: provenance (task id, seed) differs"),
            );
        }
        if a.steps.len() != b.steps.len() {
            note(
                &mut result,
                format!(
                    "episode {index}: {} frames became {}",
                    a.steps.len(),
                    b.steps.len()
                ),
            );
            continue;
        }
        if video_differs(&a, &b) {
            note(&mut result, format!("episode {index}: video differs"));
        }
        for (frame, (x, y)) in a.steps.iter().zip(&b.steps).enumerate() {
            let what = if both(FeatureKind::Rgb) && rgb_differs(&x.rgb, &y.rgb) {
                Some("RGB")
            } else if both(FeatureKind::Mask) && x.mask != y.mask {
                Some("mask")
            } else if both(FeatureKind::Depth)
                && (x.depth_m.len() != y.depth_m.len()
                    || x.depth_m
                        .iter()
                        .zip(&y.depth_m)
                        .any(|(p, q)| (p - q).abs() > DEPTH_TOLERANCE_M))
            {
                Some("depth")
            } else if x.state.map(f32::to_bits) != y.state.map(f32::to_bits) {
                Some("state")
            } else if x.action.map(f32::to_bits) != y.action.map(f32::to_bits) {
                Some("action")
            } else if both(FeatureKind::EnvironmentState)
                && x.environment_state.map(f32::to_bits) != y.environment_state.map(f32::to_bits)
            {
                Some("object poses")
            } else if others_differ(
                &named(&a_others, &x.other),
                &named(&b_others, &y.other),
                rgb_mean_tolerance,
            ) {
                Some("another feature")
            } else {
                None
            };
            if let Some(what) = what {
                note(
                    &mut result,
                    format!("episode {index} frame {frame}: {what} differs"),
                );
                break;
            }
        }
    }
}
