//! What a format's writer is to its callers: [`EpisodeSink`] (consecutive episodes in, a
//! [`Summary`] out, `finish` safe twice), its extension for pipelines that encode apart from it,
//! collect's and convert's ([`PipelinedSink`]: encoders detached from the sink, whose
//! [`Encoded`] tickets the sink redeems), and the checks every sink makes before it writes an
//! episode.

use crate::episode::{Episode, Pixels, Step};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;

/// What a sink wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub episodes: u64,
    pub frames: u64,
    pub files: u64,
    pub bytes: u64,
}

/// Seconds a sink spent, for reports (never written into a dataset).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SinkTiming {
    /// Encoding images and video: thread-seconds when a detached encoder did it (summed over
    /// the threads), else wall seconds of the batches' parallel encoding (statistics included
    /// where the format does not count them apart).
    pub encode_secs: f64,
    /// Computing statistics (thread-seconds; 0 where the format does not count them apart).
    pub stats_secs: f64,
    /// Building tables and writing files.
    pub write_secs: f64,
}

/// An episode encoded for one sink by its detached encoder, ahead of its turn: a ticket for
/// what the encoder made, which the sink that made the encoder holds until
/// [`PipelinedSink::write_encoded`] redeems it (typed all the way: nothing is cast back).
#[derive(Debug, PartialEq, Eq)]
pub struct Encoded {
    /// Which sink's encoder issued it (a number no other sink of the process has).
    pub(crate) issuer: u64,
    /// The encoder's count of episodes encoded before it.
    pub(crate) number: u64,
}

/// Encodes episodes for a sink on any thread, apart from the sink (see
/// [`Pipelined::encoder`]). It checks the sizes of the images it encodes, which
/// [`PipelinedSink::write_encoded`] then leaves out of its checks.
pub trait DetachedEncoder: Send + Sync {
    fn encode(&self, episode: &Episode) -> Result<Encoded, ExportError>;
    /// An encoder of one episode frame by frame while it is recorded, so that each frame is
    /// encoded while its pixels are in the core's cache and its buffers can be drawn into
    /// again; `None` when the sink needs whole episodes. `expected_frames` sizes its buffers.
    fn frames(&self, _expected_frames: usize) -> Option<Box<dyn FrameEncoder>> {
        None
    }
}

/// Encodes one episode frame by frame (see [`DetachedEncoder::frames`]): the same bytes as
/// [`DetachedEncoder::encode`] of the whole episode.
pub trait FrameEncoder: Send {
    /// Takes the next step's images (it is kept without them) to encode them and take its
    /// statistics, in small batches; returns the buffers of earlier steps it is done with.
    fn push(&mut self, step: &mut Step) -> Result<Vec<Pixels>, ExportError>;
    /// The episode whose steps were pushed, encoded (its steps' pixels may be gone).
    fn finish(self: Box<Self>, episode: &Episode) -> Result<Encoded, ExportError>;
}

/// Receives consecutive episodes, in episode-index order, and writes one dataset.
pub trait EpisodeSink {
    /// Writes consecutive episodes (a sink may work on them in parallel; the output is as if
    /// they were written one by one). An episode out of order or not matching the dataset's
    /// features is rejected.
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError>;
    /// Index of the next episode the sink expects (after a resume: the first one to rewrite).
    fn next_episode_index(&self) -> u64;
    /// Completes the dataset: after this returns Ok, it is consistent and loadable. Calling it
    /// again returns the same summary and writes nothing.
    fn finish(&mut self) -> Result<Summary, ExportError> {
        self.finish_with(None)
    }
    /// [`EpisodeSink::finish`], writing `sidecar`'s file (made from the summary; e.g. a run's
    /// report) into the folder after the dataset's own files and before the dataset is marked
    /// complete, so an interrupted finish leaves a resumable dataset, never one without it.
    /// Sidecar files are not in the manifest.
    fn finish_with(&mut self, sidecar: Option<Sidecar<'_>>) -> Result<Summary, ExportError>;
    /// Whether the sink copies a source's stored still images of `encoding` (PNG, TIFF, JPEG)
    /// instead of encoding the pixels again (see [`crate::export::writer::FormatWriter::reuses_stored`]).
    fn reuses_stored(&self, _encoding: crate::episode::ImageEncoding) -> bool {
        true
    }
    /// Whether the sink writes an episode part by part as it comes
    /// ([`EpisodeSink::write_part`]), holding none of it whole: LeRobot does; the others take
    /// whole episodes ([`crate::export::source::Gathering`] makes them of parts).
    fn writes_parts(&self) -> bool {
        false
    }
    /// Writes the next part of an episode (see [`crate::export::source::EpisodePart`]): the first part
    /// of the episode the sink expects, then the rest of it in order. A sink that does not
    /// write parts ([`EpisodeSink::writes_parts`]) refuses them.
    fn write_part(&mut self, part: &crate::export::source::EpisodePart) -> Result<(), ExportError> {
        Err(ExportError::Internal(format!(
            "episode {}: this format takes whole episodes, not parts",
            part.episode.meta.index
        )))
    }
    /// Files another tool wrote beside the data (path relative to the dataset's root, bytes;
    /// [`crate::export::DatasetFormat::carried_files`]), to write as they are, listed in the
    /// manifest, when the dataset is finished. A sink that writes no such files leaves them.
    fn carry_files(&mut self, _files: Vec<(String, Vec<u8>)>) {}
    /// Time spent so far.
    fn timing(&self) -> SinkTiming {
        SinkTiming::default()
    }
    /// The sink's pipelined side, when it can encode apart from itself (collect's and convert's
    /// pipelines); `None`: it encodes inside [`EpisodeSink::write_batch`].
    fn pipelined(&mut self) -> Option<Pipelined<'_>> {
        None
    }
}

/// A sink whose episodes can be encoded apart from it: a producer encodes each episode on its
/// own threads as soon as it is made ([`Pipelined::encoder`]), and the sink only appends. The
/// bytes are those of [`EpisodeSink::write_batch`].
pub trait PipelinedSink: EpisodeSink {
    /// Writes consecutive episodes with what the sink's encoder made of each.
    fn write_encoded(&mut self, episodes: Vec<(Episode, Encoded)>) -> Result<(), ExportError>;
}

/// A sink's pipelined side (see [`EpisodeSink::pipelined`]).
pub struct Pipelined<'a> {
    /// Encodes episodes on any thread; the [`Encoded`] tickets it issues are `sink`'s to
    /// redeem.
    pub encoder: std::sync::Arc<dyn DetachedEncoder>,
    /// Appends what `encoder` made.
    pub sink: &'a mut (dyn PipelinedSink + Send),
}

/// That the dataset is not finished yet and that `episode` is the `expected` one.
fn check_order(finished: bool, episode: &Episode, expected: u64) -> Result<(), ExportError> {
    if finished {
        return Err(ExportError::Internal(
            "an episode arrived after the dataset was finished".into(),
        ));
    }
    if episode.meta.index != expected {
        return Err(ExportError::InvalidEpisode(format!(
            "episode index {} arrived where {expected} was expected (episodes must come in order)",
            episode.meta.index
        )));
    }
    Ok(())
}

/// That an episode's video can be copied as it is (exit 2 if not: the user's choice), that its
/// steps hold the dataset's features and that its images have the dataset's size. Where the
/// episode is encoded apart from its sink, its encoder checks this and the sink only the order
/// ([`check_batch_order`]).
pub(crate) fn check_content(info: &DatasetInfo, episode: &Episode) -> Result<(), ExportError> {
    // Video that cannot be copied (the user's choice to copy it, not a defect): exit 2.
    if let Some(video) = episode.encoded.iter().find(|e| {
        e.shown.is_some()
            && info
                .features
                .iter()
                .any(|f| f.name == e.feature && !f.in_steps())
    }) {
        return Err(ExportError::InvalidOptions(format!(
            "episode {}: {}'s video is not one frame per row in presentation order (B-frames, or frames the rows skip), so it cannot be copied as it is: decode it (convert --decode for images, or --video with another codec than the input's to re-encode it)",
            episode.meta.index, video.feature
        )));
    }
    episode
        .validate_structure(&info.features)
        .map_err(ExportError::InvalidEpisode)?;
    let (width, height) = info.image_size();
    episode
        .validate_pixels(width, height, &info.features)
        .map_err(ExportError::InvalidEpisode)
}

/// What every sink checks before it writes consecutive episodes starting at `first`: that
/// the dataset is not finished yet, that the episodes are the expected ones (episodes come in
/// index order), and their content ([`check_content`]).
pub(crate) fn check_batch(
    info: &DatasetInfo,
    finished: bool,
    episodes: &[Episode],
    first: u64,
) -> Result<(), ExportError> {
    check_batch_order(finished, episodes, first)?;
    (episodes.iter()).try_for_each(|episode| check_content(info, episode))
}

/// [`check_order`] for consecutive episodes starting at `first` (alone: where their content
/// was checked when they were encoded).
pub(crate) fn check_batch_order(
    finished: bool,
    episodes: &[Episode],
    first: u64,
) -> Result<(), ExportError> {
    (first..)
        .zip(episodes)
        .try_for_each(|(index, episode)| check_order(finished, episode, index))
}

/// Makes the files to write beside a finished dataset from its summary: (relative path, bytes)
/// each.
pub type Sidecar<'a> =
    &'a mut (dyn FnMut(&Summary) -> Result<Vec<(String, Vec<u8>)>, ExportError> + Send);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{
        Dtype, EncodedFeature, EpisodeMeta, FeatureKind, FeatureSpec, ImageEncoding, VideoCodec,
    };

    /// A dataset with one video camera, and an episode at `index` whose video is copyable or
    /// not (frames not one per row in presentation order).
    fn with_video(index: u64, copyable: bool) -> (DatasetInfo, Episode) {
        let camera = FeatureSpec {
            name: "observation.images.endoscope".into(),
            kind: FeatureKind::Rgb,
            dtype: Dtype::Image,
            shape: vec![4, 4, 3],
            video: Some(VideoCodec::Av1),
            info: Default::default(),
            names: Vec::new(),
        };
        let info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 5, "r", vec![camera]);
        let episode = Episode {
            meta: EpisodeMeta::foreign(index, "lift".into()),
            steps: vec![crate::episode::Step::empty()],
            encoded: vec![EncodedFeature {
                feature: "observation.images.endoscope".into(),
                encoding: ImageEncoding::Video(VideoCodec::Av1),
                frames: vec![crate::episode::EncodedFrame {
                    data: vec![0],
                    keyframe: true,
                }],
                pixel_stats: None,
                shown: (!copyable).then(|| vec![0]),
                file: None,
            }],
            image_stats: Vec::new(),
            stored_rows: None,
        };
        (info, episode)
    }

    /// A batch's order is checked before any episode's content: an episode out of order is
    /// reported (exit 1) even when an earlier one's video cannot be copied (exit 2), which is
    /// reported when the order is right.
    #[test]
    fn a_batch_reports_its_order_before_its_content() {
        let (info, uncopyable) = with_video(0, false);
        let (_, late) = with_video(2, true);
        let (_, next) = with_video(1, true);
        let mixed = check_batch(&info, false, &[uncopyable.clone(), late], 0);
        assert!(
            matches!(mixed, Err(ExportError::InvalidEpisode(_))),
            "{mixed:?}"
        );
        let content = check_batch(&info, false, &[uncopyable, next.clone()], 0);
        assert!(
            matches!(content, Err(ExportError::InvalidOptions(_))),
            "{content:?}"
        );
        let (_, first) = with_video(0, true);
        let fine = check_batch(&info, false, &[first, next], 0);
        assert!(fine.is_ok(), "{fine:?}");
    }
}
