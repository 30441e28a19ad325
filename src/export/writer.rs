//! The writer core: what every format's sink shares, written once. [`Writer`] implements
//! [`EpisodeSink`] for any [`FormatWriter`]: it owns the dataset folder ([`DatasetDir`],
//! created or resumed with the format's byte-changing options) and the [`DatasetInfo`] (lent
//! to the format's encoder, append and finish), checks each batch (order,
//! features, not finished), encodes a batch's episodes in parallel and appends them in index
//! order (so the bytes equal one-by-one writing), keeps the timing and the "finished once"
//! summary, and seals the dataset (manifest, sidecar, marker). A format says only how an
//! episode is encoded, appended and finished.

use crate::episode::{Episode, ImageEncoding, Pixels, Step};
use crate::export::card::{CARD, TALLY_JOURNAL, Tally};
use crate::export::dir::{DatasetDir, RunOptions};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::sink::DetachedEncoder;
use crate::export::sink::Encoded;
use crate::export::sink::EpisodeSink;
use crate::export::sink::FrameEncoder;
use crate::export::sink::Pipelined;
use crate::export::sink::PipelinedSink;
use crate::export::sink::Sidecar;
use crate::export::sink::SinkTiming;
use crate::export::sink::Summary;
use crate::export::sink::{check_batch, check_batch_order, check_content};
use rayon::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::path::Path;
use std::time::Instant;

/// One format's part of a sink: the rest is [`Writer`]'s.
pub trait FormatWriter: Send + Sized {
    /// The format's own options.
    type Options;
    /// What a checkpoint records besides the files.
    type State: Serialize + DeserializeOwned;
    /// One episode made ready to append; made for a batch's episodes in parallel.
    type Encoded: Send + 'static;
    /// What encodes episodes, shared by a batch's threads (a view of the writer).
    type Encoder<'a>: EpisodeEncoder<Self::Encoded>
    where
        Self: 'a;
    /// The manifest's path in the folder.
    const MANIFEST: &'static str;

    /// What the dataset card says of the format: its name and data files
    /// ([`crate::export::card`]).
    fn card_format(&self) -> crate::export::card::CardFormat;

    /// Refuses options the dataset cannot have; returns what its bytes depend on (a resume
    /// with other values is refused).
    fn run_options(info: &DatasetInfo, options: &Self::Options) -> Result<RunOptions, ExportError>;

    /// The folders (relative; "" for the root) a resume prunes back to its checkpoint.
    fn owned_folders(options: &Self::Options) -> Vec<String>;

    /// The format's writer for a dataset of `info` in `dir`, fresh (`state` None) or at a
    /// checkpoint's state.
    fn new(
        dir: &DatasetDir,
        info: &DatasetInfo,
        options: Self::Options,
        state: Option<Self::State>,
    ) -> Result<Self, ExportError>;

    /// Episodes written so far: the index of the next one.
    fn episodes(&self) -> u64;

    /// Whether the encoder copies a source's stored still images (PNG, TIFF, JPEG) of this
    /// encoding instead of encoding pixels; a conversion drops the others as it reads them, so
    /// a batch in flight does not hold every frame twice.
    fn reuses_stored(&self, _encoding: ImageEncoding) -> bool {
        true
    }

    /// The writer's encoder (no file is touched; it runs in parallel across a batch).
    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> Self::Encoder<'a>;

    /// An encoder that owns what it needs, so episodes can be encoded on other threads while
    /// the writer appends earlier ones (see [`EpisodeSink::detached_encoder`]); it may do more
    /// of the work than [`FormatWriter::encoder`] (the bytes are the same either way). `None`:
    /// the format encodes only in its batches.
    fn detached_encoder(
        &self,
        _info: &DatasetInfo,
    ) -> Option<std::sync::Arc<dyn EpisodeEncoder<Self::Encoded> + Send>> {
        None
    }

    /// Appends an encoded episode to the folder (in index order); returns the seconds of it
    /// spent encoding what the encoder left (counted as encoding, not writing).
    fn append(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        episode: &Episode,
        encoded: Self::Encoded,
    ) -> Result<f64, ExportError>;

    /// Whether [`FormatWriter::append_part`] writes episodes part by part.
    fn appends_parts(&self) -> bool {
        false
    }

    /// Appends the next part of an episode (see [`crate::export::source::EpisodePart`]; checked by the
    /// caller: the first part is the episode expected, the rest follow in order); returns
    /// the seconds spent encoding. Only where [`FormatWriter::appends_parts`].
    fn append_part(
        &mut self,
        _dir: &mut DatasetDir,
        _info: &DatasetInfo,
        part: &crate::export::source::EpisodePart,
    ) -> Result<f64, ExportError> {
        Err(ExportError::Internal(format!(
            "episode {}: this format takes whole episodes, not parts",
            part.episode.meta.index
        )))
    }

    /// Thread-seconds its detached encoder spent so far encoding, and computing statistics
    /// (counted apart from encoding).
    fn apart_secs(&self) -> (f64, f64) {
        (0.0, 0.0)
    }

    /// Checkpoints and writes the format's own last files; returns the summary so far, which
    /// [`Writer`] completes when it seals the folder.
    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError>;
}

/// Encodes one episode for appending; called from several threads at once.
pub trait EpisodeEncoder<T>: Sync {
    fn encode(&self, episode: &Episode) -> Result<T, ExportError>;
    /// An encoder of one episode frame by frame (see [`DetachedEncoder::frames`]); `None`: whole
    /// episodes only.
    fn frames(&self, _expected_frames: usize) -> Option<Box<dyn EpisodeFrames<T>>> {
        None
    }
}

/// A format's encoder of one episode frame by frame (see [`FrameEncoder`]).
pub trait EpisodeFrames<T>: Send {
    fn push(&mut self, step: &mut Step) -> Result<Vec<Pixels>, ExportError>;
    fn finish(self: Box<Self>, episode: &Episode) -> Result<T, ExportError>;
}

/// What a detached encoder made, held for its writer until an [`Encoded`] ticket redeems it.
struct Held<T> {
    /// This store's number among every writer's of the process (what its tickets carry).
    issuer: u64,
    encoded: std::sync::Mutex<std::collections::HashMap<u64, T>>,
    /// Tickets issued so far (the next ticket's number).
    issued: std::sync::atomic::AtomicU64,
}

/// Stores made so far in the process: the next one's issuer number.
static ISSUERS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl<T> Held<T> {
    fn new() -> std::sync::Arc<Self> {
        std::sync::Arc::new(Held {
            issuer: ISSUERS.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            encoded: std::sync::Mutex::new(std::collections::HashMap::new()),
            issued: std::sync::atomic::AtomicU64::new(0),
        })
    }

    /// Holds `encoded` and returns its ticket.
    fn hold(&self, encoded: T) -> Encoded {
        let number = self
            .issued
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut held = self.encoded.lock().unwrap_or_else(|e| e.into_inner());
        held.insert(number, encoded);
        Encoded {
            issuer: self.issuer,
            number,
        }
    }

    /// What `ticket` stands for; an error for another sink's ticket or one redeemed before.
    fn redeem(&self, ticket: &Encoded) -> Result<T, ExportError> {
        let mut held = self.encoded.lock().unwrap_or_else(|e| e.into_inner());
        (ticket.issuer == self.issuer)
            .then(|| held.remove(&ticket.number))
            .flatten()
            .ok_or_else(|| {
                ExportError::Internal("an episode encoded for another sink, or twice".into())
            })
    }
}

/// A format's detached encoder as a sink's (what it makes held for the writer), with the
/// dataset it checks the episodes against.
struct Detached<T> {
    encoder: std::sync::Arc<dyn EpisodeEncoder<T> + Send>,
    held: std::sync::Arc<Held<T>>,
    info: DatasetInfo,
}

impl<T: Send + 'static> DetachedEncoder for Detached<T> {
    fn encode(&self, episode: &Episode) -> Result<Encoded, ExportError> {
        // Another dataset's episodes come here too (`convert`): checked before they are
        // encoded, as the sink checks those it encodes itself; the sink checks their order.
        check_content(&self.info, episode)?;
        Ok(self.held.hold(self.encoder.encode(episode)?))
    }

    fn frames(&self, expected_frames: usize) -> Option<Box<dyn FrameEncoder>> {
        let frames = self.encoder.frames(expected_frames)?;
        Some(Box::new(DetachedFrames {
            frames,
            held: self.held.clone(),
        }))
    }
}

/// A format's frame-by-frame encoder as a sink's (what it makes held for the writer).
struct DetachedFrames<T> {
    frames: Box<dyn EpisodeFrames<T>>,
    held: std::sync::Arc<Held<T>>,
}

impl<T: Send + 'static> FrameEncoder for DetachedFrames<T> {
    fn push(&mut self, step: &mut Step) -> Result<Vec<Pixels>, ExportError> {
        self.frames.push(step)
    }

    fn finish(self: Box<Self>, episode: &Episode) -> Result<Encoded, ExportError> {
        let DetachedFrames { frames, held } = *self;
        Ok(held.hold(frames.finish(episode)?))
    }
}

/// A sink of any format: see the module overview.
pub struct Writer<F: FormatWriter> {
    /// The one owner of the folder.
    dir: DatasetDir,
    /// The dataset, stated once.
    info: DatasetInfo,
    format: F,
    timing: SinkTiming,
    /// Set by the first successful finish.
    finished: Option<Summary>,
    /// The format's detached encoder, made once, and what it encoded until appended; None
    /// when the format encodes only in batches.
    detached: Option<std::sync::Arc<dyn DetachedEncoder>>,
    held: std::sync::Arc<Held<F::Encoded>>,
    /// Files another tool wrote beside the data, written as they are when finishing
    /// ([`EpisodeSink::carry_files`]).
    carried: Vec<(String, Vec<u8>)>,
}

impl<F: FormatWriter> Writer<F> {
    /// Starts a dataset of `info` in `root`, which must not exist or be empty.
    pub fn create(
        root: &Path,
        info: &DatasetInfo,
        options: F::Options,
    ) -> Result<Self, ExportError> {
        Self::open(root, info, options, false)
    }

    /// Continues an interrupted dataset in `root` (one with the incomplete marker): refuses
    /// other info or options than it was started with, and files its checkpoint lists that are
    /// missing or changed; restores the state of the last checkpoint and deletes whatever was
    /// written after it in the format's folders; the next episode to write is
    /// [`EpisodeSink::next_episode_index`]. With the same info, options and episodes, the
    /// finished dataset is byte-identical to an uninterrupted run.
    pub fn resume(
        root: &Path,
        info: &DatasetInfo,
        options: F::Options,
    ) -> Result<Self, ExportError> {
        Self::open(root, info, options, true)
    }

    /// [`Writer::resume`] when `resuming`, else [`Writer::create`].
    pub fn open(
        root: &Path,
        info: &DatasetInfo,
        options: F::Options,
        resuming: bool,
    ) -> Result<Self, ExportError> {
        let run = F::run_options(info, &options)?;
        let (dir, state) = if resuming {
            let owned = F::owned_folders(&options);
            let owned: Vec<&str> = owned.iter().map(String::as_str).collect();
            DatasetDir::resume::<F::State>(root, &run, &owned)?
        } else {
            (DatasetDir::create(root, &run)?, None)
        };
        let format = F::new(&dir, info, options, state)?;
        let held = Held::new();
        let detached = format.detached_encoder(info).map(|encoder| {
            let detached: std::sync::Arc<dyn DetachedEncoder> = std::sync::Arc::new(Detached {
                encoder,
                held: held.clone(),
                info: info.clone(),
            });
            detached
        });
        Ok(Writer {
            format,
            dir,
            info: info.clone(),
            timing: SinkTiming::default(),
            finished: None,
            detached,
            held,
            carried: Vec::new(),
        })
    }

    /// [`Writer::open`] as a sink (what a format's `open_sink` returns).
    pub fn boxed(
        root: &Path,
        info: &DatasetInfo,
        options: F::Options,
        resuming: bool,
    ) -> Result<Box<dyn EpisodeSink + Send>, ExportError>
    where
        F: 'static,
    {
        Ok(Box::new(Self::open(root, info, options, resuming)?))
    }
}

impl<F: FormatWriter> EpisodeSink for Writer<F> {
    fn carry_files(&mut self, files: Vec<(String, Vec<u8>)>) {
        self.carried = files;
    }

    fn reuses_stored(&self, encoding: ImageEncoding) -> bool {
        self.format.reuses_stored(encoding)
    }

    /// A batch's episodes are encoded in parallel, then appended in order.
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError> {
        check_batch(
            &self.info,
            self.finished.is_some(),
            episodes,
            self.format.episodes(),
        )?;
        let started = Instant::now();
        let encoded: Vec<F::Encoded> = {
            let encoder = self.format.encoder(&self.info);
            if episodes.len() < 2 {
                episodes
                    .iter()
                    .map(|e| encoder.encode(e))
                    .collect::<Result<_, _>>()?
            } else {
                episodes
                    .par_iter()
                    .map(|e| encoder.encode(e))
                    .collect::<Result<_, _>>()?
            }
        };
        self.timing.encode_secs += started.elapsed().as_secs_f64();
        self.append_all(episodes, encoded.into_iter().map(Ok))
    }

    fn writes_parts(&self) -> bool {
        self.format.appends_parts()
    }

    /// Each part is checked as an episode (the one the format expects: it counts an episode
    /// when its last part is appended); the card's line goes with the last part.
    fn write_part(&mut self, part: &crate::export::source::EpisodePart) -> Result<(), ExportError> {
        check_batch(
            &self.info,
            self.finished.is_some(),
            std::slice::from_ref(&part.episode),
            self.format.episodes(),
        )?;
        let appending = Instant::now();
        if part.last {
            let meta = &part.episode.meta;
            let line = crate::export::card::Tally::line_of(meta, part.steps_so_far());
            self.dir.append(TALLY_JOURNAL, line.as_bytes())?;
        }
        let encoding_secs = self.format.append_part(&mut self.dir, &self.info, part)?;
        self.timing.encode_secs += encoding_secs;
        self.timing.write_secs += appending.elapsed().as_secs_f64() - encoding_secs;
        Ok(())
    }

    fn pipelined(&mut self) -> Option<Pipelined<'_>> {
        let encoder = self.detached.clone()?;
        Some(Pipelined {
            encoder,
            sink: self,
        })
    }

    fn next_episode_index(&self) -> u64 {
        self.format.episodes()
    }

    fn timing(&self) -> SinkTiming {
        let (encode_secs, stats_secs) = self.format.apart_secs();
        SinkTiming {
            encode_secs: self.timing.encode_secs + encode_secs,
            stats_secs,
            ..self.timing
        }
    }

    /// Finishing, in an order that an interruption at any point can resume: the format's
    /// checkpoint and last files, the manifest, the sidecar (the run's report), and only then
    /// the marker goes (see [`DatasetDir::complete`]). A second call returns the same summary.
    fn finish_with(&mut self, sidecar: Option<Sidecar<'_>>) -> Result<Summary, ExportError> {
        if let Some(summary) = &self.finished {
            return Ok(summary.clone());
        }
        let mut summary = self.format.finish(&mut self.dir, &self.info)?;
        let mut tally = Tally::default();
        for line in self.dir.journal_lines(TALLY_JOURNAL)? {
            tally.add_line(&line?);
        }
        for (relative, bytes) in &self.carried {
            summary.bytes += self.dir.write_atomically(relative, bytes)?;
            summary.files += 1;
        }
        let card = crate::export::card::render(&self.info, &tally, &self.format.card_format());
        summary.bytes += self.dir.write_atomically(CARD, card.as_bytes())?;
        summary.files += 1;
        summary.bytes += self.dir.write_manifest(F::MANIFEST)?;
        summary.files += 1;
        if let Some(make) = sidecar {
            for (relative, bytes) in make(&summary)? {
                self.dir.write_unlisted(&relative, &bytes)?;
            }
        }
        self.dir.complete()?;
        self.finished = Some(summary.clone());
        Ok(summary)
    }
}

impl<F: FormatWriter> PipelinedSink for Writer<F> {
    /// Appends in order what the detached encoder made of each episode.
    fn write_encoded(&mut self, episodes: Vec<(Episode, Encoded)>) -> Result<(), ExportError> {
        let (episodes, encoded): (Vec<Episode>, Vec<Encoded>) = episodes.into_iter().unzip();
        // The detached encoder checked each episode's content before it encoded it.
        check_batch_order(self.finished.is_some(), &episodes, self.format.episodes())?;
        let held = self.held.clone();
        self.append_all(&episodes, encoded.iter().map(|e| held.redeem(e)))
    }
}

impl<F: FormatWriter> Writer<F> {
    /// Appends each episode with what was encoded of it, in order: the card's line first, so
    /// that a checkpoint the append makes holds it.
    fn append_all(
        &mut self,
        episodes: &[Episode],
        encoded: impl IntoIterator<Item = Result<F::Encoded, ExportError>>,
    ) -> Result<(), ExportError> {
        let appending = Instant::now();
        let mut encoding_secs = 0.0;
        for (episode, encoded) in episodes.iter().zip(encoded) {
            let encoded = encoded?;
            self.dir
                .append(TALLY_JOURNAL, Tally::line(episode).as_bytes())?;
            encoding_secs += self
                .format
                .append(&mut self.dir, &self.info, episode, encoded)?;
        }
        self.timing.encode_secs += encoding_secs;
        self.timing.write_secs += appending.elapsed().as_secs_f64() - encoding_secs;
        Ok(())
    }
}

/// What formats that write files per episode (MCAP: one per episode; point clouds: one per
/// frame) keep: counts, a journal of episode lines that becomes `episodes.jsonl`, and a
/// checkpoint every so many episodes. It is their checkpoint state.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct EpisodeFiles {
    episodes: u64,
    summary: Summary,
}

/// The hidden journal of episode lines.
const EPISODE_LINES: &str = ".surgvla-episodes.jsonl";

impl EpisodeFiles {
    /// Episodes written.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// Writes one file of the episode being appended and counts it.
    pub fn write_file(
        &mut self,
        dir: &mut DatasetDir,
        relative: &str,
        bytes: &[u8],
    ) -> Result<(), ExportError> {
        self.summary.bytes += dir.write_atomically(relative, bytes)?;
        self.summary.files += 1;
        Ok(())
    }

    /// Records an appended episode: its line (index, its `file` where one file holds it,
    /// frames, provenance), the counts, and a checkpoint every `checkpoint_every` episodes.
    pub fn episode_done(
        &mut self,
        dir: &mut DatasetDir,
        episode: &Episode,
        file: Option<&str>,
        checkpoint_every: u64,
        ours: bool,
    ) -> Result<(), ExportError> {
        let meta = &episode.meta;
        let mut line = serde_json::Map::new();
        line.insert("episode_index".into(), meta.index.into());
        if let Some(file) = file {
            line.insert("file".into(), file.into());
        }
        let frames = episode.steps.len() as u64;
        line.insert("frames".into(), frames.into());
        // Provenance only where surgvla made the episode; another tool's per-episode values
        // as they were read.
        if ours {
            line.insert("task_id".into(), meta.task_code.clone().into());
            line.insert("level".into(), meta.level.into());
            line.insert("seed".into(), meta.seed.into());
            line.insert("success".into(), meta.success.into());
        }
        line.insert("instruction".into(), meta.instruction.clone().into());
        if !meta.fields.is_empty() {
            line.insert("fields".into(), meta.fields.clone().into());
        }
        dir.append(
            EPISODE_LINES,
            serde_json::Value::Object(line).to_string().as_bytes(),
        )?;
        self.episodes += 1;
        self.summary.episodes += 1;
        self.summary.frames += frames;
        if self.episodes.is_multiple_of(checkpoint_every) {
            dir.save_checkpoint(self)?;
        }
        Ok(())
    }

    /// Checkpoints and writes `episodes_jsonl` from the journal; returns the summary so far.
    pub fn finish(
        &self,
        dir: &mut DatasetDir,
        episodes_jsonl: &str,
    ) -> Result<Summary, ExportError> {
        dir.save_checkpoint(self)?;
        let mut summary = self.summary.clone();
        let lines = dir.journal_bytes(EPISODE_LINES)?;
        summary.bytes += dir.write_atomically(episodes_jsonl, &lines)?;
        summary.files += 1;
        Ok(summary)
    }
}
