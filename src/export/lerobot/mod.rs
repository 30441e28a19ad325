//! The LeRobot v3.0 writer.
//!
//! Layout (what `lerobot.datasets.LeRobotDataset` 0.6 reads):
//! ```text
//! meta/info.json                          written last: its presence marks a complete dataset
//! meta/stats.json                         min, max, mean, std, count, q01..q99 per feature
//! meta/tasks.parquet                      task_index, task (pandas-indexed by task)
//! meta/episodes/chunk-000/file-000.parquet
//! meta/surgvla.json                       camera intrinsics and pose, mask ids, versions
//! data/chunk-CCC/file-FFF.parquet         frames; one row group per episode, rolled by size
//! ```
//! Images are embedded: RGB and mask as PNG, depth as float32 TIFF in metres
//! (`is_depth_map`, `depth_unit: "m"`). Crash safety: files are written under temporary names
//! and renamed when complete; `.surgvla-incomplete` exists until `finish` succeeds, and
//! `meta/info.json` (without which LeRobot refuses the folder) is the last file written.

pub mod read;
mod table;

pub use table::{DEFAULT_COLUMNS, frame_schema, image_fields};

use crate::episode::{Dtype, Episode, FeatureKind, FeatureSpec, standard_features};
use crate::export::stats::{ImageStats, VectorStats};
use crate::export::tiff::encode_f32_tiff;
pub use crate::export::video::Codec;
use crate::export::video::{EncodedFrame, VideoFile, encode, video_path};
use crate::export::{
    EpisodeSink, ExportError, SinkTiming, Summary, temporary_name, write_atomically,
};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;
use rayon::prelude::*;
use serde_json::{Value, json};
use std::collections::HashMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use table::{EncodedImages, EpisodeRow, VideoSpan, episodes_batch, frame_batch, tasks_batch};

/// Name of the marker that exists while a dataset is being written.
pub const INCOMPLETE_MARKER: &str = ".surgvla-incomplete";
/// The codebase version written to info.json.
pub const CODEBASE_VERSION: &str = "v3.0";

/// PNG compression for embedded images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngLevel {
    Fast,
    Default,
    Best,
}

/// Options of the LeRobot writer.
#[derive(Clone, Debug, PartialEq)]
pub struct LeRobotOptions {
    pub fps: u32,
    pub robot_type: String,
    pub height_px: usize,
    pub width_px: usize,
    /// Also store the segmentation mask as an image feature.
    pub with_mask: bool,
    /// A new data file starts once the current one reaches this size.
    pub data_file_size_mb: u64,
    /// Files per chunk folder.
    pub chunks_size: u64,
    pub png: PngLevel,
    /// Written to meta/surgvla.json (camera, mask ids, versions).
    pub extra_metadata: Value,
    /// Store the RGB camera as H.264 MP4 (video mode) instead of PNG in the parquet.
    pub video: Option<VideoOptions>,
    /// The on-disk layout.
    pub version: LeRobotVersion,
}

/// The LeRobot layout to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LeRobotVersion {
    /// v3.0: many episodes per data and video file, parquet metadata (lerobot >= 0.4).
    #[default]
    V30,
    /// v2.1: one parquet (and MP4) per episode, JSON-lines metadata (older consumers).
    V21,
}

/// Video mode settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VideoOptions {
    pub codec: Codec,
    /// Quality: H.264's largest quantiser (0 best .. 51), AV1's quantizer (0 best .. 255).
    pub quality: u32,
    /// A new video file starts once the current one reaches this size.
    pub file_size_mb: u64,
}

impl VideoOptions {
    /// H.264 at a high-quality quantiser range (the fast mode).
    pub fn h264() -> Self {
        VideoOptions {
            codec: Codec::H264,
            quality: 22,
            file_size_mb: 200,
        }
    }
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions {
            codec: Codec::Av1,
            quality: 80,
            file_size_mb: 200,
        }
    }
}

impl Default for LeRobotOptions {
    fn default() -> Self {
        LeRobotOptions {
            fps: 5,
            robot_type: "dvrk_psm".into(),
            height_px: 224,
            width_px: 224,
            with_mask: false,
            data_file_size_mb: 100,
            chunks_size: 1000,
            png: PngLevel::Fast,
            extra_metadata: Value::Null,
            video: None,
            version: LeRobotVersion::V30,
        }
    }
}

/// Statistics of one feature (or default column).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
enum FeatureStats {
    Vector(VectorStats),
    Image(ImageStats),
}

impl FeatureStats {
    fn for_feature(feature: &FeatureSpec) -> Self {
        match feature.kind {
            FeatureKind::Rgb => FeatureStats::Image(ImageStats::unit_scaled(3)),
            FeatureKind::Mask => FeatureStats::Image(ImageStats::unit_scaled(1)),
            FeatureKind::Depth => FeatureStats::Image(ImageStats::depth()),
            _ => FeatureStats::Vector(VectorStats::new(feature.shape[0])),
        }
    }

    fn to_json(&self) -> Value {
        match self {
            FeatureStats::Vector(s) => s.to_json(),
            FeatureStats::Image(s) => s.to_json(),
        }
    }
}

/// The data file being written.
struct OpenFile {
    writer: ArrowWriter<File>,
    chunk: u64,
    file: u64,
    temporary: PathBuf,
    path: PathBuf,
}

/// Streams episodes into a LeRobot v3.0 dataset.
pub struct LeRobotWriter {
    root: PathBuf,
    options: LeRobotOptions,
    features: Vec<FeatureSpec>,
    /// The features stored in the parquet (all but video ones).
    parquet_features: Vec<FeatureSpec>,
    schema: std::sync::Arc<arrow_schema::Schema>,
    video: Option<VideoFile>,
    next_video_file: u64,
    open: Option<OpenFile>,
    next_file: u64,
    tasks: Vec<String>,
    task_lookup: HashMap<String, u64>,
    episodes: Vec<EpisodeRow>,
    total_frames: u64,
    stats: Vec<(String, FeatureStats)>,
    summary: Summary,
    /// Completed data and video files, relative to the root.
    finalized: Vec<String>,
    timing: SinkTiming,
}

fn png_bytes(
    width: usize,
    height: usize,
    colour: png::ColorType,
    pixels: &[u8],
    level: PngLevel,
) -> Result<Vec<u8>, ExportError> {
    let mut out = Vec::with_capacity(pixels.len() / 2);
    let mut encoder = png::Encoder::new(&mut out, width as u32, height as u32);
    encoder.set_color(colour);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(match level {
        PngLevel::Fast => png::Compression::Fast,
        PngLevel::Default => png::Compression::Balanced,
        PngLevel::Best => png::Compression::High,
    });
    let encode_error = |e: png::EncodingError| ExportError::Encode {
        what: "PNG".into(),
        message: e.to_string(),
    };
    let mut writer = encoder.write_header().map_err(encode_error)?;
    writer.write_image_data(pixels).map_err(encode_error)?;
    writer.finish().map_err(encode_error)?;
    Ok(out)
}

fn default_stats() -> Vec<(String, FeatureStats)> {
    DEFAULT_COLUMNS
        .iter()
        .map(|name| (name.to_string(), FeatureStats::Vector(VectorStats::new(1))))
        .collect()
}

fn write_parquet(path: &Path, batch: &arrow_array::RecordBatch) -> Result<u64, ExportError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(ExportError::io(parent))?;
    }
    let temporary = temporary_name(path);
    let file = File::create(&temporary).map_err(ExportError::io(&temporary))?;
    let parquet_error = |source| ExportError::Parquet {
        path: path.to_path_buf(),
        source,
    };
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .build();
    let mut writer =
        ArrowWriter::try_new(file, batch.schema(), Some(props)).map_err(parquet_error)?;
    writer.write(batch).map_err(parquet_error)?;
    writer.close().map_err(parquet_error)?;
    std::fs::rename(&temporary, path).map_err(ExportError::io(path))?;
    Ok(std::fs::metadata(path).map(|m| m.len()).unwrap_or(0))
}

impl LeRobotWriter {
    /// Starts a dataset in `root`, which must not exist or be empty.
    pub fn create(root: &Path, options: LeRobotOptions) -> Result<Self, ExportError> {
        if root.exists() {
            let mut entries = std::fs::read_dir(root).map_err(ExportError::io(root))?;
            if entries.next().is_some() {
                return Err(ExportError::NotEmpty {
                    path: root.to_path_buf(),
                });
            }
        }
        std::fs::create_dir_all(root).map_err(ExportError::io(root))?;
        let marker = root.join(INCOMPLETE_MARKER);
        std::fs::write(
            &marker,
            b"surgvla is writing this dataset; it is not complete\n",
        )
        .map_err(ExportError::io(&marker))?;
        Ok(LeRobotWriter::fresh(root, options))
    }

    /// A writer with empty state (no file-system checks).
    fn fresh(root: &Path, options: LeRobotOptions) -> Self {
        let features = standard_features(options.height_px, options.width_px, options.with_mask);
        let parquet_features: Vec<FeatureSpec> = features
            .iter()
            .filter(|f| !(options.video.is_some() && f.kind == FeatureKind::Rgb))
            .cloned()
            .collect();
        let mut stats: Vec<(String, FeatureStats)> = features
            .iter()
            .map(|f| (f.name.clone(), FeatureStats::for_feature(f)))
            .collect();
        stats.extend(default_stats());
        LeRobotWriter {
            root: root.to_path_buf(),
            finalized: Vec::new(),
            schema: frame_schema(&parquet_features),
            parquet_features,
            video: None,
            next_video_file: 0,
            features,
            options,
            open: None,
            next_file: 0,
            tasks: Vec::new(),
            task_lookup: HashMap::new(),
            episodes: Vec::new(),
            total_frames: 0,
            stats,
            summary: Summary::default(),
            timing: SinkTiming::default(),
        }
    }

    fn writer_properties(&self) -> WriterProperties {
        let mut builder = WriterProperties::builder()
            .set_compression(Compression::ZSTD(ZstdLevel::try_new(1).unwrap_or_default()))
            .set_created_by(format!("surgvla {}", env!("CARGO_PKG_VERSION")))
            .set_max_row_group_row_count(None);
        // PNG bytes are already deflated: store them as they are. Raw float TIFF depth keeps
        // zstd. No dictionaries for image bytes.
        for feature in self
            .parquet_features
            .iter()
            .filter(|f| f.dtype == Dtype::Image)
        {
            let column = ColumnPath::new(vec![feature.name.clone(), "bytes".into()]);
            builder = builder.set_column_dictionary_enabled(column.clone(), false);
            if feature.kind != FeatureKind::Depth {
                builder = builder.set_column_compression(column, Compression::UNCOMPRESSED);
            }
        }
        builder.build()
    }

    /// (chunk, file) of the next data or video file: v3.0 numbers files by `counter`, `chunks_size`
    /// to a chunk; v2.1 has one file per episode, numbered by the episode index.
    fn next_location(&self, counter: u64) -> (u64, u64) {
        let chunks = self.options.chunks_size.max(1);
        match self.options.version {
            LeRobotVersion::V30 => (counter / chunks, counter % chunks),
            LeRobotVersion::V21 => {
                let episode = self.episodes.len() as u64;
                (episode / chunks, episode)
            }
        }
    }

    fn open_file(&mut self) -> Result<&mut OpenFile, ExportError> {
        if self.open.is_none() {
            let (chunk, file) = self.next_location(self.next_file);
            let path = self.root.join(match self.options.version {
                LeRobotVersion::V30 => format!("data/chunk-{chunk:03}/file-{file:03}.parquet"),
                LeRobotVersion::V21 => format!("data/chunk-{chunk:03}/episode_{file:06}.parquet"),
            });
            self.next_file += 1;
            let folder = path
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| self.root.clone());
            std::fs::create_dir_all(&folder).map_err(ExportError::io(&folder))?;
            let temporary = temporary_name(&path);
            let handle = File::create(&temporary).map_err(ExportError::io(&temporary))?;
            let writer =
                ArrowWriter::try_new(handle, self.schema.clone(), Some(self.writer_properties()))
                    .map_err(|source| ExportError::Parquet {
                    path: path.clone(),
                    source,
                })?;
            self.open = Some(OpenFile {
                writer,
                chunk,
                file,
                temporary,
                path,
            });
        }
        self.open
            .as_mut()
            .ok_or_else(|| ExportError::Internal("no open data file".into()))
    }

    fn close_file(&mut self) -> Result<(), ExportError> {
        if let Some(open) = self.open.take() {
            let path = open.path.clone();
            open.writer.close().map_err(|source| ExportError::Parquet {
                path: path.clone(),
                source,
            })?;
            std::fs::rename(&open.temporary, &path).map_err(ExportError::io(&path))?;
            self.finalized.push(self.relative(&path));
            self.summary.files += 1;
            self.summary.bytes += std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        }
        Ok(())
    }

    fn info_json(&self) -> Value {
        let mut features = features_json(&self.features);
        if self.options.video.is_some() {
            features[RGB_KEY]["dtype"] = json!("video");
            features[RGB_KEY]["info"] = json!({
                "video.height": self.options.height_px,
                "video.width": self.options.width_px,
                "video.codec": self.options.video.map_or("h264", |v| v.codec.name()),
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": false,
                "video.fps": self.options.fps,
                "video.channels": 3,
                "has_audio": false,
            });
        }
        json!({
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.options.robot_type,
            "total_episodes": self.episodes.len(),
            "total_frames": self.total_frames,
            "total_tasks": self.tasks.len(),
            "chunks_size": self.options.chunks_size,
            "data_files_size_in_mb": self.options.data_file_size_mb,
            "video_files_size_in_mb": self.options.video.map_or(VideoOptions::default().file_size_mb, |v| v.file_size_mb),
            "fps": self.options.fps,
            "splits": {"train": format!("0:{}", self.episodes.len())},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": if self.options.video.is_some() {
                json!("videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4")
            } else {
                Value::Null
            },
            "features": features,
        })
    }

    /// Appends an episode's encoded frames to the open video file (opening or rolling files);
    /// returns (chunk, file, from_timestamp, to_timestamp).
    fn append_video(&mut self, frames: &[EncodedFrame]) -> Result<VideoSpan, ExportError> {
        let limit = self.options.video.map_or(200, |v| v.file_size_mb) * 1024 * 1024;
        let v21 = self.options.version == LeRobotVersion::V21;
        if self
            .video
            .as_ref()
            .is_some_and(|v| v21 || v.bytes() >= limit)
        {
            self.close_video()?;
        }
        if self.video.is_none() {
            let (chunk, file) = self.next_location(self.next_video_file);
            let path = if v21 {
                self.root.join(format!(
                    "videos/chunk-{chunk:03}/{RGB_KEY}/episode_{file:06}.mp4"
                ))
            } else {
                video_path(&self.root, RGB_KEY, chunk, file)
            };
            self.next_video_file += 1;
            let codec = self.options.video.map_or(Codec::Av1, |v| v.codec);
            self.video = Some(VideoFile::create(
                path,
                codec,
                chunk,
                file,
                self.options.width_px,
                self.options.height_px,
                self.options.fps,
            )?);
        }
        let video = self
            .video
            .as_mut()
            .ok_or_else(|| ExportError::Internal("no open video file".into()))?;
        let (from, to) = video.append(frames)?;
        Ok(VideoSpan {
            chunk: video.chunk,
            file: video.file,
            from_secs: from,
            to_secs: to,
        })
    }

    fn close_video(&mut self) -> Result<(), ExportError> {
        if let Some(video) = self.video.take() {
            let relative = self.relative(&video.path);
            self.summary.bytes += video.finish()?;
            self.finalized.push(relative);
            self.summary.files += 1;
        }
        Ok(())
    }
}

impl LeRobotWriter {
    /// The v2.1 metadata: info.json, episodes.jsonl, tasks.jsonl, episodes_stats.jsonl and
    /// stats.json; info.json last.
    fn finish_v21(mut self: Box<Self>) -> Result<Summary, ExportError> {
        let meta = self.root.join("meta");
        let lines =
            |values: Vec<Value>| -> String { values.iter().map(|v| format!("{v}\n")).collect() };
        let episodes = lines(self.episodes.iter().map(|e| json!({"episode_index": e.episode_index, "tasks": [e.task], "length": e.length})).collect());
        let tasks = lines(
            self.tasks
                .iter()
                .enumerate()
                .map(|(i, t)| json!({"task_index": i, "task": t}))
                .collect(),
        );
        let episode_stats = lines(
            self.episodes
                .iter()
                .map(|e| json!({"episode_index": e.episode_index, "stats": e.stats}))
                .collect(),
        );
        let stats: serde_json::Map<String, Value> = self
            .stats
            .iter()
            .map(|(name, s)| (name.clone(), s.to_json()))
            .collect();
        let stats = serde_json::to_string_pretty(&Value::Object(stats))
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        let extra = serde_json::to_string_pretty(&self.options.extra_metadata)
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        let mut info = self.info_json();
        let chunks = (self.episodes.len() as u64).div_ceil(self.options.chunks_size.max(1));
        info["codebase_version"] = json!("v2.1");
        info["total_chunks"] = json!(chunks);
        info["total_videos"] = json!(if self.options.video.is_some() {
            self.episodes.len()
        } else {
            0
        });
        info["data_path"] =
            json!("data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet");
        if self.options.video.is_some() {
            info["video_path"] = json!(
                "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
            );
        }
        if let Some(object) = info.as_object_mut() {
            object.remove("data_files_size_in_mb");
            object.remove("video_files_size_in_mb");
        }
        let info = serde_json::to_string_pretty(&info)
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        for (name, text) in [
            ("episodes.jsonl", &episodes),
            ("tasks.jsonl", &tasks),
            ("episodes_stats.jsonl", &episode_stats),
            ("stats.json", &stats),
            ("surgvla.json", &extra),
            ("info.json", &info),
        ] {
            write_atomically(&meta.join(name), text.as_bytes())?;
            self.summary.files += 1;
            self.summary.bytes += text.len() as u64;
        }
        let checkpoint = self.root.join(CHECKPOINT);
        if checkpoint.exists() {
            std::fs::remove_file(&checkpoint).map_err(ExportError::io(&checkpoint))?;
        }
        let marker = self.root.join(INCOMPLETE_MARKER);
        std::fs::remove_file(&marker).map_err(ExportError::io(&marker))?;
        Ok(self.summary.clone())
    }
}

/// Name of the checkpoint written whenever every file so far is complete.
pub const CHECKPOINT: &str = "meta/.surgvla-checkpoint.json";

/// The writer's state at a moment when every data and video file it wrote is complete.
#[derive(serde::Serialize, serde::Deserialize)]
struct Checkpoint {
    finalized: Vec<String>,
    next_file: u64,
    next_video_file: u64,
    tasks: Vec<String>,
    episodes: Vec<EpisodeRow>,
    total_frames: u64,
    stats: Vec<(String, FeatureStats)>,
    summary: Summary,
}

impl LeRobotWriter {
    /// Records the state after all open files were closed (see [`LeRobotWriter::resume`]).
    fn checkpoint(&self) -> Result<(), ExportError> {
        let checkpoint = Checkpoint {
            finalized: self.finalized.clone(),
            next_file: self.next_file,
            next_video_file: self.next_video_file,
            tasks: self.tasks.clone(),
            episodes: self.episodes.clone(),
            total_frames: self.total_frames,
            stats: self.stats.clone(),
            summary: self.summary.clone(),
        };
        let text =
            serde_json::to_vec(&checkpoint).map_err(|e| ExportError::Internal(e.to_string()))?;
        write_atomically(&self.root.join(CHECKPOINT), &text)
    }

    /// Continues an interrupted dataset in `root` (one with the incomplete marker): restores the
    /// state of the last checkpoint, deletes whatever was written after it, and returns the
    /// writer; the next episode to write is [`LeRobotWriter::next_episode_index`]. With the same
    /// options and episodes, the finished dataset is byte-identical to an uninterrupted run.
    pub fn resume(root: &Path, options: LeRobotOptions) -> Result<Self, ExportError> {
        if !root.join(INCOMPLETE_MARKER).exists() {
            return Err(ExportError::NotResumable {
                path: root.to_path_buf(),
                reason: "it is not an interrupted surgvla dataset (no .surgvla-incomplete marker)"
                    .into(),
            });
        }
        let checkpoint_path = root.join(CHECKPOINT);
        let checkpoint: Option<Checkpoint> = match std::fs::read(&checkpoint_path) {
            Ok(bytes) => {
                Some(
                    serde_json::from_slice(&bytes).map_err(|e| ExportError::NotResumable {
                        path: checkpoint_path.clone(),
                        reason: format!("unreadable checkpoint: {e}"),
                    })?,
                )
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => {
                return Err(ExportError::Io {
                    path: checkpoint_path,
                    source: e,
                });
            }
        };
        // Every data or video file the checkpoint does not list was written after it: it goes.
        let keep: std::collections::HashSet<String> = checkpoint
            .as_ref()
            .map(|c| c.finalized.iter().cloned().collect())
            .unwrap_or_default();
        let mut writer = LeRobotWriter::fresh(root, options);
        for folder in ["data", "videos"] {
            let mut pending = vec![root.join(folder)];
            while let Some(dir) = pending.pop() {
                let Ok(entries) = std::fs::read_dir(&dir) else {
                    continue;
                };
                for entry in entries {
                    let path = entry.map_err(ExportError::io(&dir))?.path();
                    if path.is_dir() {
                        pending.push(path);
                    } else if !keep.contains(&writer.relative(&path)) {
                        std::fs::remove_file(&path).map_err(ExportError::io(&path))?;
                    }
                }
            }
        }
        if let Some(checkpoint) = checkpoint {
            writer.finalized = checkpoint.finalized;
            writer.next_file = checkpoint.next_file;
            writer.next_video_file = checkpoint.next_video_file;
            writer.task_lookup = checkpoint
                .tasks
                .iter()
                .enumerate()
                .map(|(i, t)| (t.clone(), i as u64))
                .collect();
            writer.tasks = checkpoint.tasks;
            writer.episodes = checkpoint.episodes;
            writer.total_frames = checkpoint.total_frames;
            writer.stats = checkpoint.stats;
            writer.summary = checkpoint.summary;
        } else {
            writer.next_file = 0;
        }
        Ok(writer)
    }

    fn relative(&self, path: &Path) -> String {
        path.strip_prefix(&self.root)
            .unwrap_or(path)
            .to_string_lossy()
            .into_owned()
    }

    /// Index of the next episode this writer expects.
    pub fn next_episode_index(&self) -> u64 {
        self.episodes.len() as u64
    }
}

/// The key of the RGB camera.
pub const RGB_KEY: &str = "observation.images.endoscope";

/// The `features` object of info.json for these features (defaults appended): what
/// `schemas/lerobot_features.json` records.
pub fn features_json(feature_specs: &[FeatureSpec]) -> Value {
    let mut features = serde_json::Map::new();
    for f in feature_specs {
        let mut entry = json!({
            "dtype": match f.dtype { Dtype::Image => "image", Dtype::Float32 => "float32", Dtype::Int64 => "int64" },
            "shape": f.shape,
            "names": f.names,
        });
        if f.kind == FeatureKind::Depth {
            entry["info"] = json!({"is_depth_map": true, "depth_unit": "m"});
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
    Value::Object(features)
}

/// The per-episode work that needs only the features and options (so it can run on threads
/// while the writer holds its non-shareable parquet state).
struct EpisodeWork<'a> {
    features: &'a [FeatureSpec],
    options: &'a LeRobotOptions,
}

impl EpisodeWork<'_> {
    /// The RGB frames as H.264 (video mode only).
    fn encode_video(&self, episode: &Episode) -> Result<Option<Vec<EncodedFrame>>, ExportError> {
        let Some(video) = self.options.video else {
            return Ok(None);
        };
        let frames: Vec<&[u8]> = episode.steps.iter().map(|s| s.rgb.as_slice()).collect();
        encode(
            video.codec,
            &frames,
            self.options.width_px,
            self.options.height_px,
            self.options.fps,
            video.quality,
        )
        .map(Some)
    }

    /// Encodes every image of an episode (frames in parallel, order kept).
    fn encode_images(&self, episode: &Episode) -> Result<EncodedImages, ExportError> {
        let (w, h, level) = (
            self.options.width_px,
            self.options.height_px,
            self.options.png,
        );
        let mut images = EncodedImages::new();
        for feature in self.features.iter().filter(|f| f.dtype == Dtype::Image) {
            let kind = feature.kind;
            let encoded: Result<Vec<Vec<u8>>, ExportError> = episode
                .steps
                .par_iter()
                .map(|step| match kind {
                    FeatureKind::Rgb => png_bytes(w, h, png::ColorType::Rgb, &step.rgb, level),
                    FeatureKind::Mask => {
                        png_bytes(w, h, png::ColorType::Grayscale, &step.mask, level)
                    }
                    _ => Ok(encode_f32_tiff(w as u32, h as u32, &step.depth_m)),
                })
                .collect();
            images.insert(feature.name.clone(), encoded?);
        }
        Ok(images)
    }

    /// Statistics of one episode: frames in parallel, folded in frame order (so the result does
    /// not depend on the thread count).
    fn episode_stats(
        &self,
        episode: &Episode,
        task_index: u64,
        first_index: u64,
    ) -> Vec<(String, FeatureStats)> {
        let fresh = || -> Vec<(String, FeatureStats)> {
            let mut stats: Vec<(String, FeatureStats)> = self
                .features
                .iter()
                .map(|f| (f.name.clone(), FeatureStats::for_feature(f)))
                .collect();
            stats.extend(default_stats());
            stats
        };
        let kinds: Vec<Option<FeatureKind>> = self.features.iter().map(|f| Some(f.kind)).collect();
        let fps = f64::from(self.options.fps);
        let episode_index = episode.meta.index as f64;
        let per_frame: Vec<Vec<(String, FeatureStats)>> = episode
            .steps
            .par_iter()
            .enumerate()
            .map(|(i, step)| {
                let mut stats = fresh();
                let defaults = [
                    i as f64 / fps,
                    i as f64,
                    episode_index,
                    (first_index + i as u64) as f64,
                    task_index as f64,
                ];
                let mut default_values = defaults.iter();
                for (kind, (_, s)) in kinds
                    .iter()
                    .copied()
                    .chain(std::iter::repeat(None))
                    .zip(stats.iter_mut())
                {
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
                        (None, FeatureStats::Vector(s)) => {
                            s.push(&[default_values.next().copied().unwrap_or(0.0) as f32])
                        }
                        _ => {}
                    }
                }
                stats
            })
            .collect();
        let mut total = fresh();
        for frame in per_frame {
            for ((_, t), (_, f)) in total.iter_mut().zip(frame) {
                merge(t, f);
            }
        }
        total
    }
}

impl EpisodeSink for LeRobotWriter {
    fn write_episode(&mut self, episode: &Episode) -> Result<(), ExportError> {
        self.write_with_video(episode, None)
    }

    /// Video encoders run one per episode: a batch encodes its episodes' videos in parallel
    /// first, then writes the episodes in order.
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError> {
        if self.options.video.is_none() || episodes.len() < 2 {
            return episodes.iter().try_for_each(|e| self.write_episode(e));
        }
        let work = EpisodeWork {
            features: &self.features,
            options: &self.options,
        };
        let videos: Vec<Result<Option<Vec<EncodedFrame>>, ExportError>> =
            episodes.par_iter().map(|e| work.encode_video(e)).collect();
        for (episode, video) in episodes.iter().zip(videos) {
            self.write_with_video(episode, Some(video?))?;
        }
        Ok(())
    }

    fn timing(&self) -> SinkTiming {
        self.timing
    }

    fn finish(self: Box<Self>) -> Result<Summary, ExportError> {
        self.finish_dataset()
    }
}

impl LeRobotWriter {
    /// Writes one episode; `video` holds its already encoded frames when the caller encoded them.
    fn write_with_video(
        &mut self,
        episode: &Episode,
        video: Option<Option<Vec<EncodedFrame>>>,
    ) -> Result<(), ExportError> {
        episode.validate().map_err(ExportError::InvalidEpisode)?;
        if episode.meta.index != self.episodes.len() as u64 {
            return Err(ExportError::InvalidEpisode(format!(
                "episode index {} arrived where {} was expected (episodes must come in order)",
                episode.meta.index,
                self.episodes.len()
            )));
        }
        let task_index = match self.task_lookup.get(&episode.meta.instruction) {
            Some(i) => *i,
            None => {
                let i = self.tasks.len() as u64;
                self.tasks.push(episode.meta.instruction.clone());
                self.task_lookup.insert(episode.meta.instruction.clone(), i);
                i
            }
        };
        let first_index = self.total_frames;
        let encode_started = std::time::Instant::now();
        let work = EpisodeWork {
            features: &self.features,
            options: &self.options,
        };
        let image_work = EpisodeWork {
            features: &self.parquet_features,
            options: &self.options,
        };
        let ((images, video_frames), episode_stats) = rayon::join(
            || {
                rayon::join(
                    || image_work.encode_images(episode),
                    || match video {
                        Some(encoded) => Ok(encoded),
                        None => work.encode_video(episode),
                    },
                )
            },
            || work.episode_stats(episode, task_index, first_index),
        );
        let images = images?;
        let write_started = std::time::Instant::now();
        self.timing.encode_secs += (write_started - encode_started).as_secs_f64();
        let video_span = match video_frames? {
            Some(frames) => Some(self.append_video(&frames)?),
            None => None,
        };
        let batch = frame_batch(
            &self.schema,
            &self.parquet_features,
            episode,
            &images,
            first_index,
            task_index,
            self.options.fps,
        )?;
        let limit = self.options.data_file_size_mb * 1024 * 1024;
        let open = self.open_file()?;
        let (chunk, file, path) = (open.chunk, open.file, open.path.clone());
        let parquet_error = |source| ExportError::Parquet {
            path: path.clone(),
            source,
        };
        open.writer.write(&batch).map_err(parquet_error)?;
        open.writer.flush().map_err(parquet_error)?;
        let full = open.writer.bytes_written() as u64 >= limit
            || self.options.version == LeRobotVersion::V21;

        let mut stats_json = serde_json::Map::new();
        for ((name, total), (_, this)) in self.stats.iter_mut().zip(episode_stats) {
            stats_json.insert(name.clone(), this.to_json());
            merge(total, this);
        }
        let length = episode.steps.len() as u64;
        self.episodes.push(EpisodeRow {
            episode_index: episode.meta.index,
            task: episode.meta.instruction.clone(),
            length,
            data_chunk: chunk,
            data_file: file,
            from_index: first_index,
            to_index: first_index + length,
            stats: Value::Object(stats_json),
            video: video_span,
        });
        self.total_frames += length;
        self.summary.episodes += 1;
        self.summary.frames += length;
        if full {
            // Close the video file at the same moment, so that everything written so far is
            // complete, and record the state.
            self.close_file()?;
            self.close_video()?;
            // v3.0 closes a file every ~100 MB; v2.1 closes one per episode, so it records the
            // state every 64 episodes (the checkpoint holds every episode's row).
            let due = self.options.version == LeRobotVersion::V30 || self.episodes.len() % 64 == 0;
            if due {
                self.checkpoint()?;
            }
        }
        self.timing.write_secs += write_started.elapsed().as_secs_f64();
        Ok(())
    }

    fn finish_dataset(mut self: Box<Self>) -> Result<Summary, ExportError> {
        self.close_file()?;
        self.close_video()?;
        if self.options.version == LeRobotVersion::V21 {
            return self.finish_v21();
        }
        let meta = self.root.join("meta");
        let mut files = 0;
        let mut bytes = 0;
        let mut count = |b: u64| {
            files += 1;
            bytes += b;
        };
        count(write_parquet(
            &meta.join("tasks.parquet"),
            &tasks_batch(&self.tasks)?,
        )?);
        count(write_parquet(
            &meta.join("episodes/chunk-000/file-000.parquet"),
            &episodes_batch(&self.episodes)?,
        )?);
        let stats: serde_json::Map<String, Value> = self
            .stats
            .iter()
            .map(|(name, s)| (name.clone(), s.to_json()))
            .collect();
        let stats_text = serde_json::to_string_pretty(&Value::Object(stats))
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        write_atomically(&meta.join("stats.json"), stats_text.as_bytes())?;
        count(stats_text.len() as u64);
        let extra = serde_json::to_string_pretty(&self.options.extra_metadata)
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        write_atomically(&meta.join("surgvla.json"), extra.as_bytes())?;
        count(extra.len() as u64);
        let info = serde_json::to_string_pretty(&self.info_json())
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        write_atomically(&meta.join("info.json"), info.as_bytes())?;
        count(info.len() as u64);
        let checkpoint = self.root.join(CHECKPOINT);
        if checkpoint.exists() {
            std::fs::remove_file(&checkpoint).map_err(ExportError::io(&checkpoint))?;
        }
        let marker = self.root.join(INCOMPLETE_MARKER);
        std::fs::remove_file(&marker).map_err(ExportError::io(&marker))?;
        self.summary.files += files;
        self.summary.bytes += bytes;
        Ok(self.summary.clone())
    }
}

/// Folds one episode's statistics into the dataset's.
fn merge(total: &mut FeatureStats, part: FeatureStats) {
    match (total, part) {
        (FeatureStats::Vector(a), FeatureStats::Vector(b)) => a.merge(&b),
        (FeatureStats::Image(a), FeatureStats::Image(b)) => a.merge(&b),
        _ => {}
    }
}
