//! The LeRobot writer: [`LeRobotWriter`] appends each episode's row group (and video) to the
//! open data file, rolls files by size (each close a checkpoint), journals the episode rows, and
//! at the end writes the episodes table, tasks, statistics and `info.json` last.

use super::meta::InfoJson;
use super::meta::{FeatureStatsJson, StatsJson};
use super::options::{CODEBASE_VERSION, LeRobotOptions, VideoOptions};
use super::table::{DEFAULT_COLUMNS, Provenance, frame_schema};
use super::table::{EpisodeRow, KeyedSpan, VideoSpan, default_columns, frame_batch};
use super::work::{EpisodeStats, EpisodeWork, RowStats, fresh_stats};
use crate::episode::{Dtype, Episode, FeatureKind, FeatureSpec, VideoCodec};
use crate::export::dir::RunOptions;
use crate::export::dir::{Checksummed, DatasetDir, FileCounter, PendingFile, WrittenBehind};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::sink::Summary;
use crate::export::writer::{FormatWriter, Writer};
use crate::media::video::{EncodedFrame, Mp4Writer};
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;
use serde_json::{Value, json};
use std::collections::HashMap;

/// Where rows were written: the data file's place, and whether it is full.
pub(super) struct Written {
    chunk: u64,
    file: u64,
    full: bool,
}

/// The data file being written.
struct OpenFile {
    writer: super::copy::DataFile,
    chunk: u64,
    file: u64,
    pending: PendingFile,
}

/// A video file being written: its MP4 and its place.
struct VideoFile {
    /// Counted as written, for [`DatasetDir::commit_summed`].
    mp4: Mp4Writer<Checksummed<WrittenBehind>>,
    pending: PendingFile,
    chunk: u64,
    file: u64,
}

/// The journal of episode rows (one JSON line per episode), read back when the dataset
/// finishes, but for the rows this run still holds ([`HeldRows`]).
const EPISODES_JOURNAL: &str = "meta/.surgvla-episodes.jsonl";

/// The most journal text whose rows a run holds in memory as well (about twice this in
/// memory): past it, it holds none and finishing parses the whole journal, so that the memory a
/// run needs stays bounded however many episodes it writes.
const HELD_ROWS_BYTES: usize = 16 << 20;

/// The rows this run journaled, held so that finishing need not parse their lines back (what
/// finishing an edit spent most of its time on). The journal stays the record: a resumed run
/// parses the lines an earlier run wrote.
struct HeldRows<T> {
    /// Journal lines before the first held row (written by earlier runs).
    after: u64,
    rows: Vec<T>,
    /// Journal text of the held rows.
    bytes: usize,
}

impl<T> HeldRows<T> {
    /// None held yet, `after` journal lines written before.
    fn after(after: u64) -> Self {
        HeldRows {
            after,
            rows: Vec::new(),
            bytes: 0,
        }
    }

    /// Holds `row`, journaled as a line of `line_bytes`; false (and none to be held any more)
    /// once the held rows' lines would pass `limit` bytes.
    fn hold(&mut self, row: T, line_bytes: usize, limit: usize) -> bool {
        self.bytes = self.bytes.saturating_add(line_bytes);
        if self.bytes > limit {
            return false;
        }
        self.rows.push(row);
        true
    }
}

/// The episodes table's rows: the journal's lines written before `held`'s rows, parsed, then
/// those rows; every line parsed when none are held, or when they are not the journal's last
/// `written` - `after` rows (which they always are: the check keeps a slip from losing rows).
fn journal_then_held<'a, T: Send + 'a>(
    lines: impl Iterator<Item = Result<String, ExportError>> + Send + 'a,
    parse: &'a (dyn Fn(&String) -> Result<T, ExportError> + Sync),
    held: Option<HeldRows<T>>,
    written: u64,
) -> impl Iterator<Item = Result<T, ExportError>> + Send + 'a {
    let (before, rows) = (held.filter(|h| h.after + h.rows.len() as u64 == written))
        .map_or((usize::MAX, Vec::new()), |h| {
            (usize::try_from(h.after).unwrap_or(usize::MAX), h.rows)
        });
    parsed_in_parallel(lines.take(before), parse).chain(rows.into_iter().map(Ok))
}

/// The writer's state: everything a checkpoint records besides the files (which the
/// [`DatasetDir`] records). It is saved at moments when every data and video file written so
/// far is complete. Its size does not grow with the number of episodes (only with distinct
/// instructions).
#[derive(Clone, serde::Serialize, serde::Deserialize)]
pub struct State {
    data_files: FileCounter,
    video_files: FileCounter,
    tasks: Vec<String>,
    /// Episodes written; their rows are in [`EPISODES_JOURNAL`].
    episodes: u64,
    total_frames: u64,
    stats: EpisodeStats,
    summary: Summary,
}

/// Streams episodes into a LeRobot dataset.
pub type LeRobotWriter = Writer<LeRobotFiles>;

/// LeRobot's part of [`LeRobotWriter`].
pub struct LeRobotFiles {
    options: LeRobotOptions,
    /// The features stored in the parquet (all but the video ones).
    parquet_features: Vec<FeatureSpec>,
    /// Where each parquet [`FeatureKind::Other`] feature's value is in a step's other values.
    other_positions: Vec<usize>,
    /// The features stored as video (the RGB camera in video mode, and every feature that
    /// arrives as video), with their codec, in feature order.
    video_features: Vec<(String, VideoCodec)>,
    schema: std::sync::Arc<arrow_schema::Schema>,
    open: Option<OpenFile>,
    /// The open video files, one per video feature (opened and closed together).
    videos: Vec<VideoFile>,
    state: State,
    task_lookup: HashMap<String, u64>,
    /// Thread-seconds the detached encoder spent encoding, and on statistics.
    apart_secs: (f64, f64),
    /// The episode being appended part by part, after its first part.
    pub(super) parts: Option<super::work::OpenEpisode>,
    /// None once past [`HELD_ROWS_BYTES`] (or finished).
    held: Option<HeldRows<EpisodeRow>>,
}

impl FormatWriter for LeRobotFiles {
    type Options = LeRobotOptions;
    type State = State;
    /// The episode's video features' frames (encoded, or copied as they arrived), and from the
    /// detached encoder its images and statistics too.
    type Encoded = super::work::Prepared;
    type Encoder<'a> = EpisodeWork<'a>;
    const MANIFEST: &'static str = crate::export::dir::MANIFEST;

    fn card_format(&self) -> crate::export::card::CardFormat {
        crate::export::card::CardFormat {
            name: "lerobot",
            tagged: false,
            data_files: Some("data/*/*.parquet"),
            loading: Some(super::layout::loading_snippet(self.options.version)),
            depth: "Stored as float32 TIFF images in metres (`depth_unit: \"m\"` in the feature's info).",
            video: self
                .video_features
                .iter()
                .map(|(name, codec)| (name.clone(), codec.name()))
                .collect(),
        }
    }

    fn run_options(
        info: &DatasetInfo,
        options: &LeRobotOptions,
    ) -> Result<RunOptions, ExportError> {
        LeRobotFiles::check(info, options)
    }

    fn owned_folders(_: &LeRobotOptions) -> Vec<String> {
        ["data", "videos", "meta"].map(String::from).to_vec()
    }

    fn new(
        _: &DatasetDir,
        info: &DatasetInfo,
        options: LeRobotOptions,
        state: Option<State>,
    ) -> Result<Self, ExportError> {
        let mut writer = LeRobotFiles::fresh(info, options);
        if let Some(state) = state {
            writer.task_lookup = state
                .tasks
                .iter()
                .enumerate()
                .map(|(i, t)| (t.clone(), i as u64))
                .collect();
            writer.state = state;
        }
        writer.held = Some(HeldRows::after(writer.state.episodes));
        Ok(writer)
    }

    fn episodes(&self) -> u64 {
        self.state.episodes
    }

    /// Video encoders run one per episode, so a batch encodes its episodes' videos in
    /// parallel.
    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> EpisodeWork<'a> {
        self.work(info)
    }

    fn detached_encoder(
        &self,
        info: &DatasetInfo,
    ) -> Option<
        std::sync::Arc<dyn crate::export::writer::EpisodeEncoder<super::work::Prepared> + Send>,
    > {
        Some(std::sync::Arc::new(super::work::SharedWork(
            std::sync::Arc::new(super::work::OwnedWork {
                info: info.clone(),
                parquet_features: self.parquet_features.clone(),
                video_features: self.video_features.clone(),
                options: self.options.clone(),
            }),
        )))
    }

    fn append(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        episode: &Episode,
        prepared: super::work::Prepared,
    ) -> Result<f64, ExportError> {
        self.write_prepared(dir, info, episode, prepared)
    }

    fn apart_secs(&self) -> (f64, f64) {
        self.apart_secs
    }

    /// A recording's long episodes are written as they are read (see [`super::parts`]).
    fn appends_parts(&self) -> bool {
        true
    }

    fn append_part(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        part: &crate::export::source::EpisodePart,
    ) -> Result<f64, ExportError> {
        self.write_part(dir, info, part)
    }

    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError> {
        self.finish_dataset(dir, info)
    }
}

/// The (width, height) of the video feature `key`: its shape's, or the RGB camera's.
pub(super) fn video_size(info: &DatasetInfo, key: &str) -> (usize, usize) {
    (info.features.iter())
        .find(|f| f.name == key)
        .map_or(info.image_size(), |f| {
            (
                f.shape.get(1).copied().unwrap_or(0),
                f.shape.first().copied().unwrap_or(0),
            )
        })
}

/// Whether video mode stores `feature` as video: the RGB camera, and another dataset's
/// 3-channel cameras (channels last, as LeRobot states them).
pub(crate) fn encodes_as_video(feature: &FeatureSpec) -> bool {
    match feature.kind {
        FeatureKind::Rgb => true,
        FeatureKind::Other => {
            feature.dtype == crate::episode::Dtype::Image
                && feature.shape.len() == 3
                && feature.shape[2] == 3
        }
        _ => false,
    }
}

impl LeRobotFiles {
    /// Refuses options the dataset cannot have; returns what its bytes depend on.
    fn check(info: &DatasetInfo, options: &LeRobotOptions) -> Result<RunOptions, ExportError> {
        let arrives_as_video = info.features.iter().any(|f| !f.in_steps());
        if options.video.is_some()
            && !info.features.iter().any(encodes_as_video)
            && !arrives_as_video
        {
            // What the user asked for, not a defect of the data: exit 2.
            return Err(ExportError::InvalidOptions(
                "video mode needs an RGB camera feature, and this dataset has none: leave --video out"
                    .into(),
            ));
        }
        if let Some(video) = options.video {
            let other: Vec<String> = info
                .features
                .iter()
                .filter(|f| f.video.is_some_and(|c| c != video.codec))
                .map(|f| format!("{} ({})", f.name, f.video.map_or("", |c| c.name())))
                .collect();
            if !other.is_empty() {
                return Err(ExportError::InvalidOptions(format!(
                    "{} arrive as video in another codec than {}: decode them first (convert does: it re-encodes them), or leave the codec out to copy them as they are",
                    other.join(", "),
                    video.codec.name()
                )));
            }
            let odd = (info.features.iter())
                .filter(|f| f.in_steps() && encodes_as_video(f))
                .map(|f| (f, video_size(info, &f.name)))
                .find(|(_, (width, height))| width % 2 == 1 || height % 2 == 1);
            if let (VideoCodec::H264, Some((feature, (width, height)))) = (video.codec, odd) {
                return Err(ExportError::InvalidOptions(format!(
                    "{} is {width}x{height} pixels, and H.264 (4:2:0) needs an even width and height: give --video av1",
                    feature.name
                )));
            }
        }
        let mut run = info.run_options();
        run.merge(options.run_options());
        Ok(run)
    }

    /// A writer with empty state.
    fn fresh(info: &DatasetInfo, options: LeRobotOptions) -> Self {
        let video_features: Vec<(String, VideoCodec)> = info
            .features
            .iter()
            .filter_map(|f| {
                let codec = f.video.or(options
                    .video
                    .filter(|_| encodes_as_video(f))
                    .map(|v| v.codec))?;
                Some((f.name.clone(), codec))
            })
            .collect();
        let parquet_features: Vec<FeatureSpec> = info
            .features
            .iter()
            .filter(|f| !video_features.iter().any(|(key, _)| *key == f.name))
            .cloned()
            .collect();
        let in_steps: Vec<&str> = (info.features.iter())
            .filter(|f| f.kind == FeatureKind::Other && f.in_steps())
            .map(|f| f.name.as_str())
            .collect();
        let other_positions = (parquet_features.iter())
            .filter(|f| f.kind == FeatureKind::Other)
            .filter_map(|f| in_steps.iter().position(|name| *name == f.name))
            .collect();
        let counter = FileCounter::new(options.chunks_size);
        LeRobotFiles {
            schema: frame_schema(&parquet_features),
            parquet_features,
            other_positions,
            video_features,
            open: None,
            videos: Vec::new(),
            state: State {
                data_files: counter,
                video_files: counter,
                tasks: Vec::new(),
                episodes: 0,
                total_frames: 0,
                stats: fresh_stats(&info.features),
                summary: Summary::default(),
            },
            options,
            task_lookup: HashMap::new(),
            apart_secs: (0.0, 0.0),
            parts: None,
            held: None,
        }
    }

    fn writer_properties(&self) -> WriterProperties {
        // The per-frame vectors and indices are a few hundred bytes per episode and column:
        // snappy, as LeRobot's own files, since a zstd codec costs every reader more to make
        // (its contexts ask the CPU for its features, which a virtual machine answers slowly)
        // than it saves on so few bytes, and a reader makes one per column and row group.
        let mut builder = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_created_by(format!("surgvla {}", env!("CARGO_PKG_VERSION")))
            .set_max_row_group_row_count(None);
        // PNG bytes are already deflated: store them as they are. Raw float TIFF depth, large
        // and compressible, is zstd's. No dictionaries for image bytes.
        for feature in self
            .parquet_features
            .iter()
            .filter(|f| f.dtype == Dtype::Image)
        {
            let column = ColumnPath::new(vec![feature.name.clone(), "bytes".into()]);
            builder = builder.set_column_dictionary_enabled(column.clone(), false);
            let compression = if feature.kind == FeatureKind::Depth {
                Compression::ZSTD(ZstdLevel::try_new(1).unwrap_or_default())
            } else {
                Compression::UNCOMPRESSED
            };
            builder = builder.set_column_compression(column, compression);
        }
        builder.build()
    }

    fn open_file(&mut self, dir: &mut DatasetDir) -> Result<&mut OpenFile, ExportError> {
        if self.open.is_none() {
            let episode = self.state.episodes;
            let version = self.options.version;
            let (chunk, file) = version.next_location(&mut self.state.data_files, episode);
            let (handle, pending) = dir.create_file(&version.data_path(chunk, file))?;
            let writer = super::copy::DataFile::create(
                handle,
                self.schema.clone(),
                self.writer_properties(),
            )
            .map_err(ExportError::parquet(&pending.path))?;
            self.open = Some(OpenFile {
                writer,
                chunk,
                file,
                pending,
            });
        }
        self.open
            .as_mut()
            .ok_or_else(|| ExportError::Internal("no open data file".into()))
    }

    fn close_file(&mut self, dir: &mut DatasetDir) -> Result<(), ExportError> {
        if let Some(open) = self.open.take() {
            let path = open.pending.path.clone();
            let sums = open.writer.close().map_err(ExportError::parquet(&path))?;
            let bytes = dir.commit_summed(open.pending, sums)?;
            self.state.summary.files += 1;
            self.state.summary.bytes += bytes;
        }
        Ok(())
    }

    /// The size at which video files roll, MB.
    fn video_file_size_mb(&self) -> u64 {
        self.options
            .video
            .map_or(VideoOptions::default().file_size_mb, |v| v.file_size_mb)
    }

    /// info.json as v3.0 has it.
    fn info_json(&self, info: &DatasetInfo) -> InfoJson {
        let mut features = feature_map(&info.features);
        for (key, codec) in &self.video_features {
            let shape = info
                .features
                .iter()
                .find(|f| f.name == *key)
                .map(|f| f.shape.clone())
                .unwrap_or_default();
            let dimension = |i: usize| shape.get(i).copied().unwrap_or(0);
            let entry = features.entry(key.clone()).or_insert_with(|| json!({}));
            entry["dtype"] = json!("video");
            // The feature's own facts (a camera's intrinsics) stay beside the video's.
            let own = entry.get("info").cloned();
            entry["info"] = json!({
                "video.height": dimension(0),
                "video.width": dimension(1),
                "video.codec": codec.name(),
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": false,
                "video.fps": info.fps,
                "video.channels": dimension(2),
                "has_audio": false,
            });
            if let (Some(Value::Object(own)), Some(info)) = (own, entry["info"].as_object_mut()) {
                // lerobot 0.6 spells the depth flag `is_depth_map`: a feature carrying it (and
                // the encoder's settings lerobot records, `video.g`, `video.crf`, ...) keeps
                // its own keys.
                if own.contains_key("is_depth_map") {
                    info.remove("video.is_depth_map");
                }
                for (key, value) in own {
                    info.entry(key).or_insert(value);
                }
            }
        }
        let episodes = self.state.episodes;
        InfoJson {
            codebase_version: Some(CODEBASE_VERSION.into()),
            robot_type: Some(info.robot_type.clone()),
            total_episodes: Some(episodes),
            total_frames: Some(self.state.total_frames),
            total_tasks: Some(self.state.tasks.len() as u64),
            chunks_size: Some(self.options.chunks_size),
            data_files_size_in_mb: Some(self.options.data_file_size_mb),
            video_files_size_in_mb: Some(self.video_file_size_mb()),
            fps: Some(info.fps.into()),
            splits: Some(if info.splits.is_empty() {
                [("train".to_string(), format!("0:{episodes}"))].into()
            } else {
                (info.splits.iter())
                    .map(|(name, range)| (name.clone(), format!("{}:{}", range.start, range.end)))
                    .collect()
            }),
            data_path: Some("data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet".into()),
            video_path: (!self.video_features.is_empty()).then(|| {
                "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4".into()
            }),
            features: Some(features),
            other: info.carried_keys.clone(),
            ..InfoJson::default()
        }
    }

    /// The features stored as video, with their codec.
    pub(super) fn video_features(&self) -> &[(String, VideoCodec)] {
        &self.video_features
    }

    pub(super) fn options(&self) -> &LeRobotOptions {
        &self.options
    }

    /// Frames written so far: the dataset index of the next one.
    pub(super) fn frames_written(&self) -> u64 {
        self.state.total_frames
    }

    /// What [`frame_batch`] needs of the parquet's layout.
    pub(super) fn parquet_columns(&self) -> super::table::ParquetColumns<'_> {
        super::table::ParquetColumns {
            schema: &self.schema,
            features: &self.parquet_features,
            other_positions: &self.other_positions,
        }
    }

    /// Appends an episode's frames, one list per video feature, to the open video files
    /// (opening them, or rolling them all when one is full).
    fn append_videos(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        frames: &[Vec<EncodedFrame>],
    ) -> Result<Vec<KeyedSpan>, ExportError> {
        let from = self.ready_videos(dir, info)?;
        self.append_video_packets(frames)?;
        Ok(self.video_spans(&from))
    }

    /// Makes the video files ready for an episode: opened when none is (they close with the
    /// data file, when either is full: [`LeRobotFiles::episode_done`]); returns where the
    /// episode starts in each, seconds.
    pub(super) fn ready_videos(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
    ) -> Result<Vec<f64>, ExportError> {
        let version = self.options.version;
        if self.videos.is_empty() {
            let episode = self.state.episodes;
            let location = version.next_location(&mut self.state.video_files, episode);
            for (key, codec) in self.video_features.clone() {
                let size = video_size(info, &key);
                let relative = version.video_path(&key, location.0, location.1);
                let (handle, pending) = dir.create_file(&relative)?;
                self.videos.push(VideoFile {
                    mp4: Mp4Writer::create(
                        Checksummed::new(WrittenBehind::new(handle)),
                        pending.path.clone(),
                        codec,
                        size,
                        info.fps,
                    )?,
                    pending,
                    chunk: location.0,
                    file: location.1,
                });
            }
        }
        Ok(self.videos.iter().map(|v| v.mp4.time_secs()).collect())
    }

    /// Each video feature's span of an episode that started at `from` (seconds, per feature)
    /// in the open video files and ends where they end now.
    pub(super) fn video_spans(&self, from: &[f64]) -> Vec<KeyedSpan> {
        (self.video_features.iter())
            .zip(self.videos.iter().zip(from))
            .map(|((key, _), (video, &from_secs))| KeyedSpan {
                key: key.clone(),
                span: VideoSpan {
                    chunk: video.chunk,
                    file: video.file,
                    from_secs,
                    to_secs: video.mp4.time_secs(),
                },
            })
            .collect()
    }

    /// Appends a part's packets, one list per video feature, to the open video files.
    pub(super) fn append_video_packets(
        &mut self,
        packets: &[Vec<EncodedFrame>],
    ) -> Result<(), ExportError> {
        for (video, packets) in self.videos.iter_mut().zip(packets) {
            video.mp4.append(packets)?;
        }
        Ok(())
    }

    fn close_videos(&mut self, dir: &mut DatasetDir) -> Result<(), ExportError> {
        for video in std::mem::take(&mut self.videos) {
            let sums =
                (video.mp4.finish()?.finish()).map_err(ExportError::io(&video.pending.path))?;
            self.state.summary.bytes += dir.commit_summed(video.pending, sums)?;
            self.state.summary.files += 1;
        }
        Ok(())
    }

    pub(super) fn task_index(&mut self, instruction: &str) -> u64 {
        if let Some(i) = self.task_lookup.get(instruction) {
            return *i;
        }
        let i = self.state.tasks.len() as u64;
        self.state.tasks.push(instruction.to_string());
        self.task_lookup.insert(instruction.to_string(), i);
        i
    }

    /// Each step's task index (see [`crate::episode::EpisodeMeta::instruction_at`]).
    fn task_indices(&mut self, episode: &Episode) -> Vec<u64> {
        (0..episode.steps.len())
            .map(|step| self.task_index(episode.meta.instruction_at(step)))
            .collect()
    }

    /// Writes one episode with what was made of it ahead (its video features' frames, and
    /// perhaps its images and statistics); returns the seconds spent encoding its images and
    /// statistics here.
    pub(super) fn write_prepared(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        episode: &Episode,
        prepared: super::work::Prepared,
    ) -> Result<f64, ExportError> {
        let meta = &episode.meta;
        let task_indices = self.task_indices(episode);
        let first_index = self.state.total_frames;
        let encode_started = std::time::Instant::now();
        let work = self.work(info);
        let super::work::Prepared {
            video: video_frames,
            images,
            stats,
            row_stats,
            encode_secs: encoded_ahead_secs,
            stats_secs,
        } = prepared;
        let (images, mut episode_stats) = rayon::join(
            || images.map_or_else(|| work.encode_images(episode), Ok),
            || stats.unwrap_or_else(|| work.feature_stats(episode)),
        );
        episode_stats.extend(super::work::default_stats(
            meta.index,
            f64::from(info.fps),
            &task_indices,
            first_index,
        ));
        let images = images?;
        let encode_secs = encode_started.elapsed().as_secs_f64();
        let videos = if self.video_features.is_empty() {
            Vec::new()
        } else {
            self.append_videos(dir, info, &video_frames)?
        };
        let written = match &episode.stored_rows {
            Some(stored) => {
                let defaults =
                    default_columns(meta.index, (first_index, 0), &task_indices, info.fps);
                self.copy_rows(dir, stored, &defaults)?
            }
            None => {
                let batch = frame_batch(
                    &self.parquet_columns(),
                    episode,
                    images,
                    (first_index, 0),
                    &task_indices,
                    info.fps,
                )?;
                self.write_rows(dir, &batch)?
            }
        };
        let length = episode.steps.len() as u64;
        self.episode_done(
            dir,
            info,
            meta,
            (first_index, length),
            written,
            (episode_stats, row_stats),
            videos,
        )?;
        self.apart_secs.0 += encoded_ahead_secs;
        self.apart_secs.1 += stats_secs;
        Ok(encode_secs)
    }

    /// Appends rows to the open data file (opening one) as a row group of their own; returns
    /// the file's (chunk, file) and whether it is full.
    pub(super) fn write_rows(
        &mut self,
        dir: &mut DatasetDir,
        batch: &arrow_array::RecordBatch,
    ) -> Result<Written, ExportError> {
        let limit = self.options.data_file_size_mb * 1024 * 1024;
        let version = self.options.version;
        let open = self.open_file(dir)?;
        let parquet_error = ExportError::parquet(&open.pending.path);
        open.writer.write_batch(batch).map_err(&parquet_error)?;
        Ok(Written {
            chunk: open.chunk,
            file: open.file,
            full: version.file_is_full(open.writer.bytes_written() as u64, limit),
        })
    }

    /// [`LeRobotWriter::write_rows`] for an episode whose rows its source left stored: the
    /// stored row group copied, its default columns `defaults` encoded
    /// ([`super::copy::DataFile::copy_group`]).
    fn copy_rows(
        &mut self,
        dir: &mut DatasetDir,
        stored: &crate::episode::StoredRows,
        defaults: &[arrow_array::ArrayRef],
    ) -> Result<Written, ExportError> {
        let Some(group) = stored.handle.downcast_ref::<super::copy::StoredGroup>() else {
            return Err(ExportError::Internal(
                "an episode's rows are stored in another format's file".into(),
            ));
        };
        let limit = self.options.data_file_size_mb * 1024 * 1024;
        let version = self.options.version;
        let open = self.open_file(dir)?;
        (open.writer.copy_group(group, stored, defaults))
            .map_err(ExportError::parquet(&open.pending.path))?;
        Ok(Written {
            chunk: open.chunk,
            file: open.file,
            full: version.file_is_full(open.writer.bytes_written() as u64, limit),
        })
    }

    /// Records an episode whose rows (the dataset's frames `first_index` on, `length` of them)
    /// and videos are written, the last rows as `written`: its statistics folded in (with, when
    /// they were made ahead, the first features' as its row records them), its row journaled;
    /// the data and video files close together when the data file is full (a checkpoint).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn episode_done(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        meta: &crate::episode::EpisodeMeta,
        (first_index, length): (u64, u64),
        written: Written,
        (episode_stats, row_stats): (EpisodeStats, Option<RowStats>),
        videos: Vec<KeyedSpan>,
    ) -> Result<(), ExportError> {
        let (stats_json, pixel_stats) = self.fold_stats(info, episode_stats, row_stats);
        let row = EpisodeRow {
            episode_index: meta.index,
            tasks: meta.instructions().into_iter().map(String::from).collect(),
            length,
            data_chunk: written.chunk,
            data_file: written.file,
            from_index: first_index,
            to_index: first_index + length,
            stats: stats_json,
            videos,
            pixel_stats,
            provenance: info.is_ours().then(|| Provenance::of(meta)),
            fields: meta.fields.clone(),
        };
        self.journal(dir, row)?;
        if written.full || self.videos_full() {
            // A full data or video file closes the others at the same moment, so that
            // everything written so far is complete, and the state is recorded.
            self.close_file(dir)?;
            self.close_videos(dir)?;
            if self.options.version.checkpoint_due(self.state.episodes) {
                dir.save_checkpoint(&self.state)?;
            }
        }
        Ok(())
    }

    /// Whether a video file being written reached `video_files_size_in_mb` (counting its
    /// samples: the muxer holds them until the file closes).
    fn videos_full(&self) -> bool {
        let limit = self.video_file_size_mb() * 1024 * 1024;
        (self.videos.iter())
            .any(|v| (self.options.version).file_is_full(v.mp4.bytes_written(), limit))
    }

    /// Appends an episode's row to the journal, holds it while [`HeldRows`] may, and counts
    /// the episode.
    fn journal(&mut self, dir: &mut DatasetDir, row: EpisodeRow) -> Result<(), ExportError> {
        let line = serde_json::to_vec(&row).map_err(|source| ExportError::Json {
            path: dir.path(EPISODES_JOURNAL),
            source,
        })?;
        dir.append(EPISODES_JOURNAL, &line)?;
        self.state.episodes += 1;
        self.state.total_frames += row.length;
        self.state.summary.episodes += 1;
        self.state.summary.frames += row.length;
        if let Some(held) = &mut self.held
            && !held.hold(row, line.len(), HELD_ROWS_BYTES)
        {
            self.held = None;
        }
        Ok(())
    }

    /// Folds an episode's statistics into the dataset's; returns them as its row records them,
    /// with the exact pixel statistics of its image features (surgvla's datasets: so that
    /// merging, converting or editing it later, without decoding its video or images, gives the
    /// same statistics). `made`: the first features' entries of the row, made ahead.
    fn fold_stats(
        &mut self,
        info: &DatasetInfo,
        episode_stats: EpisodeStats,
        made: Option<RowStats>,
    ) -> (StatsJson, Vec<(String, Box<serde_json::value::RawValue>)>) {
        let mut stats_json = StatsJson::new();
        let mut pixel_stats = Vec::new();
        let made = made.into_iter().flatten().map(Some);
        // (Taken out while this writer lends itself to the entries' work.)
        let mut totals = std::mem::take(&mut self.state.stats);
        let work = self.work(info);
        let folded = (totals.iter_mut())
            .zip(episode_stats)
            .zip(made.chain(std::iter::repeat_with(|| None)));
        for (((name, total), (_, this)), made) in folded {
            let (json, exact) = made.unwrap_or_else(|| work.row_entry(name, &this));
            if let Some(exact) = exact {
                pixel_stats.push((name.clone(), super::table::raw_json(exact)));
            }
            if let Some(json) = json {
                stats_json.insert(name.clone(), json);
            }
            total.merge(&this);
        }
        self.state.stats = totals;
        (stats_json, pixel_stats)
    }

    /// The per-episode work's view of this writer.
    pub(super) fn work<'a>(&'a self, info: &'a DatasetInfo) -> EpisodeWork<'a> {
        EpisodeWork {
            parallel: true,
            info,
            parquet_features: &self.parquet_features,
            video_features: &self.video_features,
            options: &self.options,
        }
    }

    /// Finishing, in an order that an interruption at any point can resume: close the files and
    /// checkpoint (every episode is durable), write the metadata and the manifest, the sidecar
    /// (the run's report), and only then remove the marker.
    fn finish_dataset(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
    ) -> Result<Summary, ExportError> {
        if let Some(open) = &self.parts {
            return Err(ExportError::Internal(format!(
                "episode {}'s last part never came",
                open.index()
            )));
        }
        self.close_file(dir)?;
        self.close_videos(dir)?;
        dir.save_checkpoint(&self.state)?;
        let stats: StatsJson = self
            .state
            .stats
            .iter()
            // Text has no statistics (lerobot leaves string features out of them too).
            .filter(|(name, _)| !info.is_text(name))
            .map(|(name, s)| (name.clone(), FeatureStatsJson::from_value(s.to_json())))
            .collect();
        let video_keys: Vec<String> = self.video_features.iter().map(|(k, _)| k.clone()).collect();
        let metadata = super::layout::Metadata {
            tasks: &self.state.tasks,
            episodes: self.state.episodes,
            stats,
            // A dataset surgvla did not make (converted from another tool's) gets no surgvla
            // metadata: it has no camera intrinsics or collection to state.
            surgvla: if info.is_ours() {
                info.surgvla_json()
            } else {
                Value::Null
            },
            info: self.info_json(info),
            chunks_size: self.options.chunks_size,
            video_keys: &video_keys,
        };
        let mut summary = self.state.summary.clone();
        let parse = |line: &String| {
            serde_json::from_str::<EpisodeRow>(line).map_err(|source| ExportError::Json {
                path: EPISODES_JOURNAL.into(),
                source,
            })
        };
        let lines = dir.journal_lines(EPISODES_JOURNAL)?;
        let rows = journal_then_held(lines, &parse, self.held.take(), self.state.episodes);
        let (files, bytes) = self.options.version.write_metadata(dir, &metadata, rows)?;
        summary.files += files;
        summary.bytes += bytes;
        Ok(summary)
    }
}

/// Journal lines read in chunks of [`PARSED_AT_ONCE`] lines (held in memory at once), each chunk
/// parsed on the pool's threads; the rows in order, then a read or parse error where it was
/// (nothing is read after a read error).
fn parsed_in_parallel<'a, T: Send + 'a>(
    mut lines: impl Iterator<Item = Result<String, ExportError>> + Send + 'a,
    parse: &'a (dyn Fn(&String) -> Result<T, ExportError> + Sync),
) -> impl Iterator<Item = Result<T, ExportError>> + Send + 'a {
    use rayon::prelude::*;
    let mut parsed = std::collections::VecDeque::new();
    // Set at a read error: nothing is read after it.
    let mut done = false;
    std::iter::from_fn(move || {
        if parsed.is_empty() && !done {
            let mut chunk = Vec::with_capacity(PARSED_AT_ONCE);
            let mut failed = None;
            for line in lines.by_ref().take(PARSED_AT_ONCE) {
                match line {
                    Ok(line) => chunk.push(line),
                    Err(error) => {
                        failed = Some(error);
                        break;
                    }
                }
            }
            done = failed.is_some();
            parsed.extend(chunk.par_iter().map(parse).collect::<Vec<_>>());
            parsed.extend(failed.map(Err));
        }
        parsed.pop_front()
    })
}

/// Journal lines [`parsed_in_parallel`] at once.
const PARSED_AT_ONCE: usize = 64;

/// The `features` object of info.json for these features (defaults appended): what
/// `schemas/lerobot_features.json` records.
pub fn features_json(feature_specs: &[FeatureSpec]) -> Value {
    Value::Object(feature_map(feature_specs))
}

/// [`features_json`]'s entries, in order.
fn feature_map(feature_specs: &[FeatureSpec]) -> serde_json::Map<String, Value> {
    let mut features = serde_json::Map::new();
    for f in feature_specs {
        let mut entry = json!({
            "dtype": match f.dtype { Dtype::Image => "image", Dtype::Float32 => "float32", Dtype::Float64 => "float64", Dtype::Int64 => "int64", Dtype::String => "string" },
            "shape": f.shape,
            // Another tool's feature without names said null (lerobot's own way), and says it again.
            "names": if f.names.is_empty() && (f.dtype == Dtype::String || f.kind == FeatureKind::Other) { Value::Null } else { json!(f.names) },
        });
        if f.kind == FeatureKind::Depth {
            entry["info"] = json!({"is_depth_map": true, "depth_unit": "m"});
        } else if !f.info.is_empty() {
            entry["info"] = Value::Object(f.info.clone());
        }
        features.insert(f.name.clone(), entry);
    }
    features.insert(
        "timestamp".into(),
        json!({"dtype": "float32", "shape": [1], "names": null}),
    );
    for name in &DEFAULT_COLUMNS[1..] {
        features.insert(
            name.to_string(),
            json!({"dtype": "int64", "shape": [1], "names": null}),
        );
    }
    features
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows are held until their journal lines pass the limit, then none are; the table's
    /// rows are the journal's earlier lines then the held rows, or every line when none are
    /// held or the held ones do not end the journal.
    #[test]
    fn held_rows_follow_the_journal_lines_before_them() {
        let mut held = HeldRows::after(3);
        assert!(held.hold(3, 10, 25) && held.hold(4, 10, 25));
        assert!(!held.hold(5, 10, 25), "30 bytes pass the limit");
        assert_eq!(held.rows, [3, 4]);
        let parse = |line: &String| {
            line.parse::<usize>()
                .map_err(|e| ExportError::Internal(format!("{line}: {e}")))
        };
        // The journal's lines, the held ones written as "1000 + row" to tell them apart.
        let journal = || (0..5).map(|i| Ok(if i < 3 { i } else { 1000 + i }.to_string()));
        let rows = |held, written| {
            journal_then_held(journal(), &parse, held, written)
                .collect::<Result<Vec<usize>, _>>()
                .expect("rows")
        };
        let two = || {
            let mut held = HeldRows::after(3);
            assert!(held.hold(3, 1, 10) && held.hold(4, 1, 10));
            held
        };
        assert_eq!(rows(Some(two()), 5), [0, 1, 2, 3, 4]);
        assert_eq!(rows(None, 5), [0, 1, 2, 1003, 1004]);
        assert_eq!(
            rows(Some(two()), 6),
            [0, 1, 2, 1003, 1004],
            "not the last rows"
        );
        assert_eq!(rows(Some(HeldRows::after(5)), 5), [0, 1, 2, 1003, 1004]);
    }

    /// Lines parsed chunk by chunk on the pool come back in order, past a chunk's end, and a
    /// read error stops them where it was.
    #[test]
    fn journal_lines_parsed_in_parallel_keep_their_order_and_errors() {
        let count = 3 * PARSED_AT_ONCE + 5;
        let parse = |line: &String| {
            line.parse::<usize>()
                .map_err(|e| ExportError::Internal(format!("{line}: {e}")))
        };
        let lines = (0..count).map(|i| Ok(i.to_string()));
        let rows: Vec<usize> = parsed_in_parallel(lines, &parse)
            .collect::<Result<_, _>>()
            .expect("every line parses");
        assert_eq!(rows, (0..count).collect::<Vec<_>>());
        let failing = PARSED_AT_ONCE + 3;
        let lines = (0..count).map(move |i| {
            if i == failing {
                Err(ExportError::Internal("unreadable".into()))
            } else {
                Ok(i.to_string())
            }
        });
        let read: Vec<Result<usize, ExportError>> = parsed_in_parallel(lines, &parse).collect();
        let first_error = read.iter().position(Result::is_err).expect("an error");
        assert_eq!(first_error, failing);
        assert_eq!(
            read.len(),
            failing + 1,
            "nothing is read after a read error"
        );
        assert!(
            read[..failing]
                .iter()
                .enumerate()
                .all(|(i, r)| matches!(r, Ok(v) if *v == i))
        );
        let bad = (0..2).map(|i| Ok(if i == 1 { "x".into() } else { i.to_string() }));
        let parsed: Vec<_> = parsed_in_parallel(bad, &parse).collect();
        assert!(matches!(parsed[..], [Ok(0), Err(_)]));
    }
}
