//! Converting a dataset: every episode of an [`EpisodeSource`] into an [`EpisodeSink`] made
//! with the source's [`DatasetInfo`](crate::export::info::DatasetInfo). Episodes travel in small
//! batches (one per worker thread, so the sink encodes them in parallel and memory stays
//! bounded by a few episodes); a resumed sink skips the episodes it already holds.

use crate::episode::{Episode, FeatureKind, ImageEncoding, MAX_OBJECTS, POSE_VALUES};
use crate::error::ErrorKind;
use crate::export::error::ExportError;
use crate::export::pipeline::{Episodes, in_order, in_order_prepared};
use crate::export::sink::EpisodeSink;
use crate::export::sink::{Pipelined, Sidecar, Summary};
use crate::export::source::{EpisodePart, EpisodeSource};

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
    /// What was asked of the input cannot be done (a shard past its episodes, video that
    /// cannot be decoded).
    #[error(transparent)]
    Input(ExportError),
}

impl crate::error::HasKind for ConvertError {
    fn kind(&self) -> ErrorKind {
        match self {
            ConvertError::Read(error) | ConvertError::Write(error) | ConvertError::Input(error) => {
                error.kind()
            }
        }
    }

    /// Whether the output's disk (or quota) is full.
    fn is_disk_full(&self) -> bool {
        matches!(self, ConvertError::Write(error) if error.is_disk_full())
    }
}

impl ConvertError {
    /// Whether writing the output failed on the file system (a full disk, an I/O error): the
    /// only failure a `--resume` can get past. A failure of the data (a value the target
    /// cannot hold, an encoder refusing a frame) fails again on every run.
    pub fn is_output_io(&self) -> bool {
        matches!(
            self,
            ConvertError::Write(ExportError::Io { .. } | ExportError::Output { .. })
        )
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
    convert_with(source, sink, threads, progress, None)
}

/// [`convert`], finishing with `sidecar`'s files beside the dataset (see
/// [`EpisodeSink::finish_with`]).
pub fn convert_with(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    threads: usize,
    progress: &mut (dyn FnMut(u64) + Send),
    sidecar: Option<Sidecar<'_>>,
) -> Result<Summary, ConvertError> {
    let pool = crate::threads::pool(threads).map_err(|e| ConvertError::Write(e.into()))?;
    pool.install(|| copy(source, sink, progress, sidecar))
}

fn copy(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    progress: &mut (dyn FnMut(u64) + Send),
    sidecar: Option<Sidecar<'_>>,
) -> Result<Summary, ConvertError> {
    let skip = sink.next_episode_index();
    let unused: Vec<ImageEncoding> = [ImageEncoding::Png, ImageEncoding::Tiff, ImageEncoding::Jpeg]
        .into_iter()
        .filter(|e| !sink.reuses_stored(*e))
        .collect();
    source.drop_stored(&unused);
    if source.makes_parts() && sink.writes_parts() {
        copy_parts(source, sink, skip, &unused, progress)?;
        return sink.finish_with(sidecar).map_err(ConvertError::Write);
    }
    let mut episodes = Episodes::of(vec![source]).skipping(skip);
    let keep_used = |mut episode: Episode| {
        episode.encoded.retain(|e| !unused.contains(&e.encoding));
        episode
    };
    if let Some(Pipelined { encoder, sink }) = sink.pipelined() {
        // Each batch is read and encoded while the one before is appended.
        let prepare = |episode: Episode| {
            let episode = keep_used(episode);
            let encoded = encoder.encode(&episode).map_err(ConvertError::Write)?;
            Ok((episode, encoded))
        };
        let mut append = |batch| sink.write_encoded(batch).map_err(ConvertError::Write);
        in_order_prepared(
            &mut episodes,
            ConvertError::Read,
            &prepare,
            &mut append,
            progress,
        )?;
    } else {
        let mut write = |batch: Vec<Episode>| {
            let batch: Vec<Episode> = batch.into_iter().map(keep_used).collect();
            sink.write_batch(&batch).map_err(ConvertError::Write)
        };
        in_order(&mut episodes, ConvertError::Read, &mut write, progress)?;
    }
    sink.finish_with(sidecar).map_err(ConvertError::Write)
}

/// Copies episodes part by part into a sink that writes them so (see [`EpisodePart`]): no
/// episode is held whole. The first `skip` episodes are passed over (a resume), stored images
/// of the `unused` encodings dropped; `progress` is told the episodes done after each one's
/// last part.
fn copy_parts(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    skip: u64,
    unused: &[ImageEncoding],
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<(), ConvertError> {
    for _ in 0..skip {
        match source.skip_episode() {
            Some(skipped) => skipped.map_err(ConvertError::Read)?,
            None => break,
        }
    }
    let mut done = skip;
    while let Some(part) = source.next_part() {
        let mut part: EpisodePart = part.map_err(ConvertError::Read)?;
        (part.episode.encoded).retain(|e| !unused.contains(&e.encoding));
        sink.write_part(&part).map_err(ConvertError::Write)?;
        if part.last {
            done += 1;
            progress(done);
        }
    }
    Ok(())
}

/// A source with some features left out (`convert --without`): they leave the dataset's
/// features and every step.
pub struct Without {
    inner: Box<dyn EpisodeSource + Send>,
    info: crate::export::info::DatasetInfo,
    kinds: Vec<FeatureKind>,
    /// Per value of the input's steps' `other`, whether it is kept.
    other_kept: Vec<bool>,
}

impl Without {
    /// `inner` without the features of `kinds` (RGB, state and action cannot be left out: they
    /// are ignored here).
    pub fn new(inner: Box<dyn EpisodeSource + Send>, kinds: &[FeatureKind]) -> Self {
        Self::with_names(inner, kinds, &[])
    }

    /// `inner` without the features of `kinds` and the other features named `names`.
    pub fn with_names(
        inner: Box<dyn EpisodeSource + Send>,
        kinds: &[FeatureKind],
        names: &[String],
    ) -> Self {
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
        let dropped = |f: &crate::episode::FeatureSpec| {
            kinds.contains(&f.kind) || (f.kind == FeatureKind::Other && names.contains(&f.name))
        };
        let other_kept = info
            .features
            .iter()
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
            .map(|f| !dropped(f))
            .collect();
        info.features.retain(|f| !dropped(f));
        Without {
            inner,
            info,
            kinds,
            other_kept,
        }
    }

    /// What `--without` values leave out of a dataset of `info`: (surgvla's optional kinds,
    /// other features by key). A value is `depth`, `mask` or `environment_state`, or a feature
    /// key of the input; anything else, and the camera, state or action, is refused naming
    /// the input's features.
    pub fn resolve(
        info: &crate::export::info::DatasetInfo,
        given: &[String],
    ) -> Result<(Vec<FeatureKind>, Vec<String>), String> {
        let (mut kinds, mut names) = (Vec::new(), Vec::new());
        for value in given {
            let kind = match value.as_str() {
                "depth" => Some(FeatureKind::Depth),
                "mask" => Some(FeatureKind::Mask),
                "environment_state" => Some(FeatureKind::EnvironmentState),
                _ => None,
            };
            if let Some(kind) = kind {
                kinds.push(kind);
                continue;
            }
            match info.features.iter().find(|f| &f.name == value) {
                Some(f) if f.kind == FeatureKind::Other => names.push(f.name.clone()),
                Some(f)
                    if matches!(
                        f.kind,
                        FeatureKind::Depth | FeatureKind::Mask | FeatureKind::EnvironmentState
                    ) =>
                {
                    kinds.push(f.kind);
                }
                Some(f) => {
                    return Err(format!(
                        "--without {value}: {} is the dataset's {:?}, which a conversion keeps",
                        f.name, f.kind
                    ));
                }
                None => {
                    let keys: Vec<&str> = info.features.iter().map(|f| f.name.as_str()).collect();
                    return Err(format!(
                        "--without {value}: the input has no such feature (depth, mask, \
                         environment_state, or one of its keys: {})",
                        keys.join(", ")
                    ));
                }
            }
        }
        Ok((kinds, names))
    }

    fn strip(&self, mut episode: Episode) -> Episode {
        let kept = &self.info.features;
        episode
            .encoded
            .retain(|e| kept.iter().any(|f| f.name == e.feature));
        let drops_other = self.other_kept.iter().any(|k| !k);
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
            if drops_other {
                let mut keep = self.other_kept.iter();
                step.other.retain(|_| keep.next().copied().unwrap_or(true));
            }
        }
        episode
    }
}
impl Iterator for Without {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let episode = self.inner.next()?;
        Some(episode.map(|e| self.strip(e)))
    }
}

impl EpisodeSource for Without {
    fn info(&self) -> &crate::export::info::DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.inner.skip_episode()
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.inner.drop_stored(unused);
    }

    fn leave_rows_stored(&mut self) {
        self.inner.leave_rows_stored();
    }

    fn taking_only(&mut self, episodes: std::sync::Arc<std::collections::BTreeSet<u64>>) {
        self.inner.taking_only(episodes);
    }

    fn skim(&mut self) -> Option<Result<crate::export::source::Skimmed, ExportError>> {
        self.inner.skim()
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

/// Whether two steps' other features (by name) differ: images at or above `min_psnr_db` (their
/// decoded pixels' [`psnr_db`]) when given, everything else exactly.
fn others_differ(
    a: &std::collections::BTreeMap<String, crate::episode::FeatureValue>,
    b: &std::collections::BTreeMap<String, crate::episode::FeatureValue>,
    min_psnr_db: Option<f64>,
) -> bool {
    use crate::episode::FeatureValue;
    // What a target that cannot hold a value as it is (RLDS) holds instead: a float image
    // (TIFF) as its values, under the name its RLDS key reads back as (`observation.images.X`
    // is `observation/X`); float64 as float32, as TFRecord stores it.
    let tensor_of_image = |name: &str, x: &FeatureValue| {
        let folded = name.replacen("observation.images.", "observation.", 1);
        match (x, b.get(name).or_else(|| b.get(&folded))) {
            (FeatureValue::Image(bytes), Some(FeatureValue::Float32(values))) => {
                crate::media::tiff::decode_f32_tiff(bytes).is_some_and(|(_, _, v)| v == *values)
            }
            (FeatureValue::Float64(doubles), Some(FeatureValue::Float32(values))) => {
                doubles.len() == values.len()
                    && doubles
                        .iter()
                        .zip(values)
                        .all(|(d, v)| (*d as f32).to_bits() == v.to_bits())
            }
            _ => false,
        }
    };
    let Some(min_psnr_db) = min_psnr_db else {
        return a.len() != b.len()
            || a.iter()
                .any(|(name, x)| Some(x) != b.get(name) && !tensor_of_image(name, x));
    };
    let pixels =
        |bytes: &[u8]| (crate::media::image::decode_8bit_sized(bytes, None).ok()).map(|p| p.3);
    a.len() != b.len()
        || a.iter().any(|(name, x)| match (x, b.get(name)) {
            // The same bytes (an image copied, a 16-bit depth map beside a re-encoded camera)
            // are the same picture without decoding.
            (FeatureValue::Image(x), Some(FeatureValue::Image(y))) if x == y => false,
            (FeatureValue::Image(x), Some(FeatureValue::Image(y))) => {
                match (pixels(x), pixels(y)) {
                    (Some(p), Some(q)) => psnr_db(&p, &q) < min_psnr_db,
                    _ => true,
                }
            }
            (x, y) => Some(x) != y && !tensor_of_image(name, x),
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

/// The lowest peak signal-to-noise ratio (dB, over a frame's bytes) at which `--verify` and
/// `validate --replay` take a lossily stored RGB frame (JPEG, re-encoded video) for its source.
/// Measured on the benchmark's frames: JPEG quality 95 keeps >= 40 dB, quality 50 >= 34.7 dB,
/// surgvla's AV1 >= 39.8 dB; a frame one step late is at 29.7 dB in the median (frames of a
/// still robot are closer, so a shift is caught on the frames where something moves).
pub const LOSSY_RGB_MIN_PSNR_DB: f64 = 30.0;

/// The peak signal-to-noise ratio of two equally long 8-bit images, dB (infinite when equal,
/// zero when their lengths differ).
pub fn psnr_db(a: &[u8], b: &[u8]) -> f64 {
    if a.len() != b.len() {
        return 0.0;
    }
    let squares: u64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| u64::from(x.abs_diff(*y)).pow(2))
        .sum();
    if squares == 0 {
        return f64::INFINITY;
    }
    let mse = squares as f64 / a.len() as f64;
    10.0 * (255.0 * 255.0 / mse).log10()
}

/// Whether an RGB frame differs from its source: exactly, or below `min_psnr_db` when given.
pub fn rgb_differs(source: &[u8], stored: &[u8], min_psnr_db: Option<f64>) -> bool {
    match min_psnr_db {
        None => source != stored,
        Some(min) => psnr_db(source, stored) < min,
    }
}

/// [`verify`], RGB frames compared by [`psnr_db`] against `rgb_min_psnr_db` when the target
/// stores them lossily (exactly when None, unless an episode's RGB is JPEG).
pub fn verify_within(
    source: &mut dyn EpisodeSource,
    target: &mut dyn EpisodeSource,
    rgb_min_psnr_db: Option<f64>,
) -> Result<Verification, ConvertError> {
    let mut result = Verification::default();
    let sides = Sides::of(source.info(), target.info());
    let note = |result: &mut Verification, text: String| {
        if result.differences.len() < 20 {
            result.differences.push(text);
        }
    };
    loop {
        let (a, b) = (source.next(), target.next());
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
        for text in meta_differences(&a, &b) {
            note(&mut result, text);
        }
        if a.steps.len() != b.steps.len() {
            continue;
        }
        // Lossy RGB on either side (JPEG): compared within the lossy tolerance.
        let jpeg = |e: &Episode| e.encoded.iter().any(|f| f.encoding == ImageEncoding::Jpeg);
        let min_psnr_db =
            rgb_min_psnr_db.or((jpeg(&a) || jpeg(&b)).then_some(LOSSY_RGB_MIN_PSNR_DB));
        if video_differs(&a, &b) {
            note(&mut result, format!("episode {index}: video differs"));
        }
        for (frame, (x, y)) in a.steps.iter().zip(&b.steps).enumerate() {
            if let Some(what) = sides.difference(x, y, min_psnr_db) {
                note(
                    &mut result,
                    format!("episode {index} frame {frame}: {what} differs"),
                );
                break;
            }
        }
    }
}

/// What differs between two episodes' metadata and lengths, each a sentence.
fn meta_differences(a: &Episode, b: &Episode) -> Vec<String> {
    let index = a.meta.index;
    let mut found = Vec::new();
    if a.meta.instruction != b.meta.instruction {
        found.push(format!(
            "episode {index}: instruction {:?} became {:?}",
            a.meta.instruction, b.meta.instruction
        ));
    }
    if a.meta.task_changes != b.meta.task_changes {
        found.push(format!(
            "episode {index}: the instruction's changes during the episode differ"
        ));
    }
    if (a.meta.seed, &a.meta.task_code) != (b.meta.seed, &b.meta.task_code) {
        found.push(format!(
            "episode {index}: provenance (task id, seed) differs"
        ));
    }
    if a.steps.len() != b.steps.len() {
        found.push(format!(
            "episode {index}: {} frames became {}",
            a.steps.len(),
            b.steps.len()
        ));
    }
    found
}

/// The two datasets [`verify_within`] compares: which features both hold, and each side's other
/// features by name (formats may order them differently).
struct Sides {
    both: Vec<FeatureKind>,
    a_others: Vec<String>,
    b_others: Vec<String>,
}

impl Sides {
    fn of(a: &crate::export::info::DatasetInfo, b: &crate::export::info::DatasetInfo) -> Self {
        let others = |info: &crate::export::info::DatasetInfo| -> Vec<String> {
            info.features
                .iter()
                .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
                .map(|f| f.name.clone())
                .collect()
        };
        let both = [
            FeatureKind::Rgb,
            FeatureKind::Mask,
            FeatureKind::Depth,
            FeatureKind::EnvironmentState,
        ]
        .into_iter()
        .filter(|kind| a.has(*kind) && b.has(*kind))
        .collect();
        Sides {
            both,
            a_others: others(a),
            b_others: others(b),
        }
    }

    /// What differs between two frames, if anything (RGB within `min_psnr_db` when lossy, depth
    /// within [`DEPTH_TOLERANCE_M`], vectors bit for bit).
    fn difference(
        &self,
        x: &crate::episode::Step,
        y: &crate::episode::Step,
        min_psnr_db: Option<f64>,
    ) -> Option<&'static str> {
        let both = |kind| self.both.contains(&kind);
        let named = |names: &[String], values: &[crate::episode::FeatureValue]| {
            names
                .iter()
                .cloned()
                .zip(values.iter().cloned())
                .collect::<std::collections::BTreeMap<_, _>>()
        };
        if both(FeatureKind::Rgb) && rgb_differs(&x.rgb, &y.rgb, min_psnr_db) {
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
            &named(&self.a_others, &x.other),
            &named(&self.b_others, &y.other),
            min_psnr_db,
        ) {
            Some("another feature")
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{Dtype, FeatureSpec};

    /// `--without` takes surgvla's names and the input's keys; it refuses what the input lacks
    /// and what a conversion keeps (the camera, state and action of a surgvla dataset).
    #[test]
    fn without_values_resolve_against_the_inputs_features() {
        let feature = |name: &str, kind| FeatureSpec {
            name: name.into(),
            dtype: Dtype::Float32,
            shape: vec![1],
            names: Vec::new(),
            kind,
            video: None,
            info: Default::default(),
        };
        let info = crate::export::info::DatasetInfo::from_surgvla_json(
            &serde_json::Value::Null,
            5,
            "r",
            vec![
                feature("observation.images.endoscope", FeatureKind::Rgb),
                feature("observation.images.depth", FeatureKind::Depth),
                feature("observation.effort", FeatureKind::Other),
            ],
        );
        let given = |values: &[&str]| {
            let values: Vec<String> = values.iter().map(|v| v.to_string()).collect();
            Without::resolve(&info, &values)
        };
        assert_eq!(
            given(&["mask", "observation.images.depth", "observation.effort"]),
            Ok((
                vec![FeatureKind::Mask, FeatureKind::Depth],
                vec!["observation.effort".to_string()]
            ))
        );
        let missing = given(&["observation.nothing"]).unwrap_err();
        assert!(missing.contains("observation.effort"), "{missing}");
        let kept = given(&["observation.images.endoscope"]).unwrap_err();
        assert!(kept.contains("keeps"), "{kept}");
    }
}
