//! The zarr store's writer: [`ZarrOptions`], and [`ZarrWriter`] appending each episode's clouds,
//! state, action (and images) to the arrays, checkpointing every [`CHECKPOINT_EPISODES`].

use super::array::{ArrayMark, ArrayWriter};
use crate::episode::Episode;
use crate::export::dir::{DatasetDir, RunOptions};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::pointcloud::{CloudSettings, RecordedCloud, frame_cloud};
use crate::export::sink::Summary;
use crate::export::writer::{EpisodeEncoder, FormatWriter, Writer};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Episodes between checkpoints.
pub const CHECKPOINT_EPISODES: u64 = 16;

/// Every file with its size and CRC-32C.
pub const MANIFEST: &str = "surgvla_manifest.json";

/// Options of the DP3 zarr store (default: the default clouds, no images, no mask channel).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ZarrOptions {
    pub cloud: CloudSettings,
    /// Also store `data/img` and `data/depth`.
    pub images: bool,
    /// A seventh point channel: the mask id of the point's pixel (needs the mask feature).
    pub mask_channel: bool,
}

impl ZarrOptions {
    /// What these options change in the bytes, by option name.
    pub fn run_options(&self) -> RunOptions {
        /// The options a zarr dataset records.
        #[derive(serde::Serialize)]
        struct Recorded {
            format: &'static str,
            #[serde(flatten)]
            cloud: RecordedCloud,
            zarr_images: bool,
            zarr_mask_channel: bool,
        }
        RunOptions::recorded(&Recorded {
            format: "zarr",
            cloud: self.cloud.recorded(),
            zarr_images: self.images,
            zarr_mask_channel: self.mask_channel,
        })
    }
}

/// What a checkpoint records besides the files.
#[derive(Clone, Default, Serialize, Deserialize)]
pub struct State {
    episode_ends: Vec<i64>,
    arrays: Vec<ArrayMark>,
    summary: Summary,
}

/// Streams episodes into a DP3 zarr store.
pub type ZarrWriter = Writer<ZarrStore>;

/// The zarr store's part of [`ZarrWriter`].
pub struct ZarrStore {
    options: ZarrOptions,
    /// point_cloud, state, action, then img and depth with images.
    arrays: Vec<ArrayWriter>,
    state: State,
}

impl ZarrStore {
    fn arrays(info: &DatasetInfo, options: &ZarrOptions) -> Vec<ArrayWriter> {
        let channels = if options.mask_channel { 7 } else { 6 };
        let mut arrays = vec![
            ArrayWriter::new(
                "data/point_cloud",
                "<f4",
                4,
                &[options.cloud.points, channels],
            ),
            ArrayWriter::new("data/state", "<f4", 4, &[7]),
            ArrayWriter::new("data/action", "<f4", 4, &[7]),
        ];
        if options.images {
            let (width, height) = info.image_size();
            arrays.push(ArrayWriter::new("data/img", "|u1", 1, &[height, width, 3]));
            arrays.push(ArrayWriter::new("data/depth", "<f4", 4, &[height, width]));
        }
        arrays
    }

    /// Writes the partial chunks and records the state.
    fn checkpoint(&mut self, dir: &mut DatasetDir) -> Result<(), ExportError> {
        for array in &self.arrays {
            array.flush(dir)?;
        }
        self.state.arrays = self.arrays.iter().map(ArrayWriter::mark).collect();
        let partial = self.arrays.iter().filter_map(ArrayWriter::partial_chunk);
        dir.save_checkpoint_rewritable(&self.state, partial.collect())
    }
}

impl FormatWriter for ZarrStore {
    type Options = ZarrOptions;
    type State = State;
    /// Each frame's cloud as little-endian float32 points.
    type Encoded = Vec<Vec<u8>>;
    type Encoder<'a> = (&'a Self, &'a DatasetInfo);
    const MANIFEST: &'static str = MANIFEST;

    fn card_format(&self) -> crate::export::card::CardFormat {
        crate::export::card::CardFormat {
            name: "zarr",
            tagged: true,
            data_files: None,
            video: Vec::new(),
        }
    }

    fn run_options(info: &DatasetInfo, options: &ZarrOptions) -> Result<RunOptions, ExportError> {
        options.cloud.options(info)?;
        if options.mask_channel && !info.has(crate::episode::FeatureKind::Mask) {
            return Err(ExportError::InvalidOptions(
                "the mask channel needs a dataset with the mask feature".into(),
            ));
        }
        let mut run = info.run_options();
        run.merge(options.run_options());
        Ok(run)
    }

    fn owned_folders(_: &ZarrOptions) -> Vec<String> {
        vec!["data".into(), "meta".into()]
    }

    fn new(
        dir: &DatasetDir,
        info: &DatasetInfo,
        options: ZarrOptions,
        state: Option<State>,
    ) -> Result<Self, ExportError> {
        let state = state.unwrap_or_default();
        let mut arrays = Self::arrays(info, &options);
        if !state.arrays.is_empty() {
            arrays = arrays
                .into_iter()
                .zip(&state.arrays)
                .map(|(array, mark)| array.resume(dir, mark))
                .collect::<Result<_, _>>()?;
        }
        Ok(ZarrStore {
            arrays,
            options,
            state,
        })
    }

    fn episodes(&self) -> u64 {
        self.state.episode_ends.len() as u64
    }

    /// Arrays hold pixels, never encoded images.
    fn reuses_stored(&self, _: crate::episode::ImageEncoding) -> bool {
        false
    }

    fn encoder<'a>(&'a self, info: &'a DatasetInfo) -> (&'a Self, &'a DatasetInfo) {
        (self, info)
    }

    fn append(
        &mut self,
        dir: &mut DatasetDir,
        _: &DatasetInfo,
        episode: &Episode,
        clouds: Vec<Vec<u8>>,
    ) -> Result<f64, ExportError> {
        let floats = |values: &mut dyn Iterator<Item = f32>| -> Vec<u8> {
            values.flat_map(f32::to_le_bytes).collect()
        };
        let steps = &episode.steps;
        let mut columns: Vec<Vec<u8>> = vec![
            clouds.concat(),
            floats(&mut steps.iter().flat_map(|s| s.state)),
            floats(&mut steps.iter().flat_map(|s| s.action)),
        ];
        if self.options.images {
            columns.push(steps.iter().flat_map(|s| s.rgb.iter().copied()).collect());
            columns.push(floats(
                &mut steps.iter().flat_map(|s| s.depth_m.iter().copied()),
            ));
        }
        for (array, bytes) in self.arrays.iter_mut().zip(&columns) {
            array.push(dir, bytes)?;
        }
        let end = self.state.episode_ends.last().copied().unwrap_or(0) + steps.len() as i64;
        self.state.episode_ends.push(end);
        self.state.summary.episodes += 1;
        self.state.summary.frames += steps.len() as u64;
        if (self.state.episode_ends.len() as u64).is_multiple_of(CHECKPOINT_EPISODES) {
            self.checkpoint(dir)?;
        }
        Ok(0.0)
    }

    fn finish(&mut self, dir: &mut DatasetDir, info: &DatasetInfo) -> Result<Summary, ExportError> {
        self.checkpoint(dir)?;
        let mut summary = self.state.summary.clone();
        let mut ends = ArrayWriter::new("meta/episode_ends", "<i8", 8, &[]);
        let end_bytes: Vec<u8> = self
            .state
            .episode_ends
            .iter()
            .flat_map(|e| e.to_le_bytes())
            .collect();
        ends.push(dir, &end_bytes)?;
        ends.flush(dir)?;
        let mut attributes = info.surgvla_json();
        attributes["fps"] = json!(info.fps);
        attributes["point_cloud"] = self.options.cloud.describe(info)?;
        attributes["point_cloud"]["channels"] = if self.options.mask_channel {
            json!(["x", "y", "z", "r", "g", "b", "mask_id"])
        } else {
            json!(["x", "y", "z", "r", "g", "b"])
        };
        let group = json!({"zarr_format": 2});
        let files = [
            (".zgroup", group.clone()),
            ("data/.zgroup", group.clone()),
            ("meta/.zgroup", group),
            (".zattrs", json!({"surgvla": attributes})),
        ];
        for array in self.arrays.iter().chain([&ends]) {
            array.write_metadata(dir)?;
        }
        for (relative, value) in files {
            let bytes = serde_json::to_vec_pretty(&value).map_err(|source| ExportError::Json {
                path: dir.path(relative),
                source,
            })?;
            dir.write_atomically(relative, &bytes)?;
        }
        // Partial chunks are rewritten as they fill: count the files as they stand.
        summary.files = dir.files().len() as u64;
        summary.bytes = dir.files().iter().map(|f| f.bytes).sum();
        Ok(summary)
    }
}

impl EpisodeEncoder<Vec<Vec<u8>>> for (&ZarrStore, &DatasetInfo) {
    fn encode(&self, episode: &Episode) -> Result<Vec<Vec<u8>>, ExportError> {
        let (store, info) = *self;
        let cloud_options = store.options.cloud.options(info)?;
        let camera = info.camera;
        let mask_channel = store.options.mask_channel;
        Ok(episode
            .steps
            .par_iter()
            .map(|step| {
                let cloud = frame_cloud(&camera, step, &cloud_options);
                let mut bytes = Vec::with_capacity(cloud.xyz_m.len() * 28);
                for i in 0..cloud.xyz_m.len() {
                    let rgb = cloud.rgb[i].map(f32::from);
                    let mut point: Vec<f32> = cloud.xyz_m[i].into_iter().chain(rgb).collect();
                    if mask_channel {
                        point.push(cloud.mask.get(i).map_or(0.0, |&id| f32::from(id)));
                    }
                    bytes.extend(point.iter().flat_map(|v| v.to_le_bytes()));
                }
                bytes
            })
            .collect())
    }
}
