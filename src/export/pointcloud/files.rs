//! [`CloudFilesWriter`]: one point-cloud file per frame, PLY or PCD, for inspection tools
//! (Open3D, PCL, CloudCompare):
//! ```text
//! episode_NNNNNN/frame_NNNNNN.ply|pcd   the frame's cloud (real points only, no padding)
//! episodes.jsonl                        per episode: index, frames, task id, level, seed, success, instruction
//! surgvla.json                          camera, mask ids, collection, the cloud settings
//! surgvla_manifest.json                 every file with size and CRC-32C
//! ```
//! Written through [`DatasetDir`]; a checkpoint every [`CHECKPOINT_EPISODES`] episodes.

use crate::episode::Episode;
use crate::export::dir::{DatasetDir, RunOptions};
use crate::export::info::DatasetInfo;
use crate::export::pointcloud::{CloudSettings, frame_cloud, pcd, ply};
use crate::export::{
    EpisodeSink, ExportError, Sidecar, SinkTiming, Summary, check_episode, finish_once, seal,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::Path;

/// Episodes between checkpoints (each lists every file so far).
pub const CHECKPOINT_EPISODES: u64 = 16;
const EPISODES_JOURNAL: &str = ".surgvla-episodes.jsonl";
/// Every file with its size and CRC-32C.
pub const MANIFEST: &str = "surgvla_manifest.json";

/// The file format of each frame's cloud.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CloudFileFormat {
    /// Binary little-endian PLY.
    Ply,
    /// Binary PCD v0.7.
    Pcd,
}

impl CloudFileFormat {
    pub fn extension(self) -> &'static str {
        match self {
            CloudFileFormat::Ply => "ply",
            CloudFileFormat::Pcd => "pcd",
        }
    }
}

/// What a checkpoint records besides the files.
#[derive(Clone, Default, Serialize, Deserialize)]
struct State {
    episodes: u64,
    summary: Summary,
}

/// Writes each frame's cloud as a file.
pub struct CloudFilesWriter {
    dir: DatasetDir,
    info: DatasetInfo,
    format: CloudFileFormat,
    settings: CloudSettings,
    state: State,
    timing: SinkTiming,
    finished: Option<Summary>,
}

impl CloudFilesWriter {
    fn run_options(
        info: &DatasetInfo,
        format: CloudFileFormat,
        settings: &CloudSettings,
    ) -> Result<RunOptions, ExportError> {
        settings.options(info)?;
        let mut run = info.run_options();
        run.set("format", json!(format));
        run.merge(settings.run_options());
        Ok(run)
    }

    /// Starts the folder `root`, which must not exist or be empty.
    pub fn create(
        root: &Path,
        info: &DatasetInfo,
        format: CloudFileFormat,
        settings: CloudSettings,
    ) -> Result<Self, ExportError> {
        let run = Self::run_options(info, format, &settings)?;
        Ok(Self::fresh(
            DatasetDir::create(root, &run)?,
            info,
            format,
            settings,
            State::default(),
        ))
    }

    /// Continues an interrupted folder from its last checkpoint.
    pub fn resume(
        root: &Path,
        info: &DatasetInfo,
        format: CloudFileFormat,
        settings: CloudSettings,
    ) -> Result<Self, ExportError> {
        let run = Self::run_options(info, format, &settings)?;
        let (dir, state) = DatasetDir::resume::<State>(root, &run, &[""])?;
        Ok(Self::fresh(
            dir,
            info,
            format,
            settings,
            state.unwrap_or_default(),
        ))
    }

    fn fresh(
        dir: DatasetDir,
        info: &DatasetInfo,
        format: CloudFileFormat,
        settings: CloudSettings,
        state: State,
    ) -> Self {
        CloudFilesWriter {
            dir,
            info: info.clone(),
            format,
            settings,
            state,
            timing: SinkTiming::default(),
            finished: None,
        }
    }

    fn write_one(&mut self, episode: &Episode) -> Result<(), ExportError> {
        check_episode(
            &self.info,
            self.finished.is_some(),
            episode,
            self.state.episodes,
        )?;
        let started = std::time::Instant::now();
        let options = self.settings.options(&self.info)?;
        let camera = self.info.camera;
        let format = self.format;
        let files: Vec<Vec<u8>> = episode
            .steps
            .par_iter()
            .map(|step| {
                let cloud = frame_cloud(&camera, step, &options);
                match format {
                    CloudFileFormat::Ply => ply::encode_ply(&cloud),
                    CloudFileFormat::Pcd => pcd::encode_pcd(&cloud),
                }
            })
            .collect();
        let written = std::time::Instant::now();
        self.timing.encode_secs += (written - started).as_secs_f64();
        let index = episode.meta.index;
        for (frame, bytes) in files.iter().enumerate() {
            let relative = format!("episode_{index:06}/frame_{frame:06}.{}", format.extension());
            self.state.summary.bytes += self.dir.write_atomically(&relative, bytes)?;
            self.state.summary.files += 1;
        }
        let meta = &episode.meta;
        let line = json!({
            "episode_index": index,
            "frames": episode.steps.len(),
            "task_id": meta.task_code,
            "level": meta.level,
            "seed": meta.seed,
            "success": meta.success,
            "instruction": meta.instruction,
        });
        self.dir
            .append(EPISODES_JOURNAL, line.to_string().as_bytes())?;
        self.state.episodes += 1;
        self.state.summary.episodes += 1;
        self.state.summary.frames += episode.steps.len() as u64;
        if self.state.episodes.is_multiple_of(CHECKPOINT_EPISODES) {
            self.dir.save_checkpoint(&self.state)?;
        }
        self.timing.write_secs += written.elapsed().as_secs_f64();
        Ok(())
    }

    fn finish_dataset(&mut self, sidecar: Option<Sidecar<'_>>) -> Result<Summary, ExportError> {
        self.dir.save_checkpoint(&self.state)?;
        let mut summary = self.state.summary.clone();
        let episodes = self.dir.journal_bytes(EPISODES_JOURNAL)?;
        let mut surgvla = self.info.surgvla_json();
        surgvla["fps"] = json!(self.info.fps);
        surgvla["point_cloud"] = self.settings.describe(&self.info)?;
        surgvla["point_cloud"]["file_format"] = json!(self.format);
        let surgvla = serde_json::to_vec_pretty(&surgvla).map_err(|source| ExportError::Json {
            path: self.dir.path("surgvla.json"),
            source,
        })?;
        for (relative, bytes) in [("episodes.jsonl", episodes), ("surgvla.json", surgvla)] {
            summary.bytes += self.dir.write_atomically(relative, &bytes)?;
            summary.files += 1;
        }
        seal(&mut self.dir, MANIFEST, summary, sidecar)
    }
}

impl EpisodeSink for CloudFilesWriter {
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError> {
        episodes.iter().try_for_each(|e| self.write_one(e))
    }

    fn next_episode_index(&self) -> u64 {
        self.state.episodes
    }

    fn timing(&self) -> SinkTiming {
        self.timing
    }

    fn finish_with(&mut self, sidecar: Option<Sidecar<'_>>) -> Result<Summary, ExportError> {
        let mut finished = self.finished.take();
        let result = finish_once(&mut finished, || self.finish_dataset(sidecar));
        self.finished = finished;
        result
    }
}
