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
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::pointcloud::cloud::{CloudSettings, frame_cloud};
use crate::export::pointcloud::{pcd, ply};
use crate::export::sink::Summary;
use crate::export::writer::{EpisodeEncoder, EpisodeFiles, FormatWriter, Writer};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Episodes between checkpoints (each lists every file so far).
pub const CHECKPOINT_EPISODES: u64 = 16;
/// One line per episode: index, frames, task id, level, seed, success, instruction.
pub const EPISODES: &str = "episodes.jsonl";
/// surgvla's metadata with the cloud settings and the file format.
pub const SURGVLA_JSON: &str = "surgvla.json";
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
    /// Every file format, in the order `--to` lists them.
    pub const ALL: [CloudFileFormat; 2] = [CloudFileFormat::Ply, CloudFileFormat::Pcd];

    pub fn extension(self) -> &'static str {
        match self {
            CloudFileFormat::Ply => "ply",
            CloudFileFormat::Pcd => "pcd",
        }
    }
}

/// Writes each frame's cloud as a file.
pub type CloudFilesWriter = Writer<CloudFiles>;

/// The point-cloud files' part of [`CloudFilesWriter`].
pub struct CloudFiles {
    format: CloudFileFormat,
    settings: CloudSettings,
    state: EpisodeFiles,
}

impl FormatWriter for CloudFiles {
    type Options = (CloudFileFormat, CloudSettings);
    type State = EpisodeFiles;
    /// Each frame's file.
    type Encoded = Vec<Vec<u8>>;
    type Encoder<'a> = (&'a Self, &'a DatasetInfo);
    const MANIFEST: &'static str = MANIFEST;

    fn card_format(&self) -> crate::export::card::CardFormat {
        crate::export::card::CardFormat {
            name: self.format.extension(),
            tagged: true,
            data_files: None,
            loading: None,
            depth: "Not stored: the point clouds are made from it.",
            video: Vec::new(),
        }
    }

    fn run_options(
        info: &DatasetInfo,
        (format, settings): &Self::Options,
    ) -> Result<RunOptions, ExportError> {
        settings.options(info)?;
        /// The options a point-cloud dataset records.
        #[derive(serde::Serialize)]
        struct Recorded {
            format: CloudFileFormat,
            #[serde(flatten)]
            cloud: super::cloud::RecordedCloud,
        }
        let mut run = info.run_options();
        run.merge(RunOptions::recorded(&Recorded {
            format: *format,
            cloud: settings.recorded(),
        }));
        Ok(run)
    }

    fn owned_folders(_: &Self::Options) -> Vec<String> {
        vec![String::new()]
    }

    fn new(
        _: &DatasetDir,
        _: &DatasetInfo,
        (format, settings): Self::Options,
        state: Option<EpisodeFiles>,
    ) -> Result<Self, ExportError> {
        Ok(CloudFiles {
            format,
            settings,
            state: state.unwrap_or_default(),
        })
    }

    fn episodes(&self) -> u64 {
        self.state.episodes()
    }

    /// Clouds are made from depth and RGB pixels, never from encoded images.
    fn reuses_stored(&self, _: crate::episode::ImageEncoding) -> bool {
        false
    }

    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> (&'a Self, &'a DatasetInfo) {
        (self, info)
    }

    fn append(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        episode: &Episode,
        files: Vec<Vec<u8>>,
    ) -> Result<f64, ExportError> {
        let index = episode.meta.index;
        let extension = self.format.extension();
        for (frame, bytes) in files.iter().enumerate() {
            let relative = format!("episode_{index:06}/frame_{frame:06}.{extension}");
            self.state.write_file(dir, &relative, bytes)?;
        }
        self.state
            .episode_done(dir, episode, None, CHECKPOINT_EPISODES, info.is_ours())?;
        Ok(0.0)
    }

    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError> {
        let mut summary = self.state.finish(dir, EPISODES)?;
        let mut surgvla = info.surgvla_json();
        surgvla["fps"] = json!(info.fps);
        surgvla["point_cloud"] = self.settings.describe(info)?;
        surgvla["point_cloud"]["file_format"] = json!(self.format);
        let surgvla = serde_json::to_vec_pretty(&surgvla).map_err(|source| ExportError::Json {
            path: dir.path(SURGVLA_JSON),
            source,
        })?;
        summary.bytes += dir.write_atomically(SURGVLA_JSON, &surgvla)?;
        summary.files += 1;
        Ok(summary)
    }
}

impl EpisodeEncoder<Vec<Vec<u8>>> for (&CloudFiles, &DatasetInfo) {
    fn encode(&self, episode: &Episode) -> Result<Vec<Vec<u8>>, ExportError> {
        let (files, info) = *self;
        let options = files.settings.options(info)?;
        let camera = info.camera;
        let format = files.format;
        Ok(episode
            .steps
            .par_iter()
            .map(|step| {
                let cloud = frame_cloud(&camera, step, &options);
                match format {
                    CloudFileFormat::Ply => ply::encode_ply(&cloud),
                    CloudFileFormat::Pcd => pcd::encode_pcd(&cloud),
                }
            })
            .collect())
    }
}
