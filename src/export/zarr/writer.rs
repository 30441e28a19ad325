//! The zarr store's writer: [`ZarrOptions`], and [`ZarrWriter`] appending each episode's clouds,
//! state, action (and images) to the arrays, checkpointing every [`CHECKPOINT_EPISODES`].

use super::array::{ArrayMark, ArrayWriter};
use crate::episode::{Dtype, Episode, FeatureKind, FeatureValue};
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
    /// The arrays and what each holds, in [`Column::of`]'s order.
    arrays: Vec<ArrayWriter>,
    columns: Vec<Column>,
    state: State,
}

/// What one `data/` array holds.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Column {
    /// Each frame's cloud.
    Cloud,
    /// surgvla's 7-D state and action.
    State,
    Action,
    /// The camera's pixels and the depth in metres.
    Img,
    Depth,
    /// Another tool's vector: the index of its value in the steps' `other`.
    Other(usize),
}

impl Column {
    /// A store's arrays: `point_cloud` with depth, `state` and `action` (surgvla's, or another
    /// tool's `observation.state` and `action` under DP3's names), `img` (and `depth`) with
    /// `--zarr-images` or when there is no cloud (Diffusion Policy's store), and every other
    /// vector under its key.
    fn of(
        info: &DatasetInfo,
        options: &ZarrOptions,
    ) -> Result<Vec<(Column, ArrayWriter)>, ExportError> {
        let clouds = info.has(FeatureKind::Depth);
        let mut arrays = Vec::new();
        if clouds {
            let channels = if options.mask_channel { 7 } else { 6 };
            let shape = [options.cloud.points, channels];
            arrays.push((
                Column::Cloud,
                ArrayWriter::new("data/point_cloud", "<f4", 4, &shape),
            ));
        }
        for (kind, column, name) in [
            (FeatureKind::State, Column::State, "data/state"),
            (FeatureKind::Action, Column::Action, "data/action"),
        ] {
            if info.has(kind) {
                arrays.push((column, ArrayWriter::new(name, "<f4", 4, &[7])));
            }
        }
        let others =
            (info.features.iter()).filter(|f| f.kind == FeatureKind::Other && f.in_steps());
        for (i, feature) in others.enumerate() {
            let name = match feature.name.as_str() {
                "observation.state" if !info.has(FeatureKind::State) => "state",
                "action" if !info.has(FeatureKind::Action) => "action",
                key => crate::export::paths::component(key).map_err(|e| {
                    ExportError::InvalidOptions(format!("the feature key {key:?}: {e}"))
                })?,
            };
            let width = [feature.shape.iter().product::<usize>()];
            let array = match feature.dtype {
                Dtype::Int64 => ArrayWriter::new(&format!("data/{name}"), "<i8", 8, &width),
                Dtype::Float64 => ArrayWriter::new(&format!("data/{name}"), "<f8", 8, &width),
                _ => ArrayWriter::new(&format!("data/{name}"), "<f4", 4, &width),
            };
            arrays.push((Column::Other(i), array));
        }
        if options.images || !clouds {
            let (width, height) = info.image_size();
            arrays.push((
                Column::Img,
                ArrayWriter::new("data/img", "|u1", 1, &[height, width, 3]),
            ));
            if clouds {
                let depth = ArrayWriter::new("data/depth", "<f4", 4, &[height, width]);
                arrays.push((Column::Depth, depth));
            }
        }
        // Another tool's `state` beside its `observation.state`, or its own `img`, would be
        // one array twice.
        for (k, (_, array)) in arrays.iter().enumerate() {
            if arrays[..k].iter().any(|(_, a)| a.name() == array.name()) {
                return Err(ExportError::InvalidOptions(format!(
                    "two of the dataset's features would be the zarr array {}: leave one out with --without",
                    array.name()
                )));
            }
        }
        Ok(arrays)
    }

    /// This column's bytes of `steps`, with `clouds` the frames' encoded clouds.
    fn bytes(self, steps: &[crate::episode::Step], clouds: &[Vec<u8>]) -> Vec<u8> {
        let floats = |values: &mut dyn Iterator<Item = f32>| -> Vec<u8> {
            values.flat_map(f32::to_le_bytes).collect()
        };
        match self {
            Column::Cloud => clouds.concat(),
            Column::State => floats(&mut steps.iter().flat_map(|s| s.state)),
            Column::Action => floats(&mut steps.iter().flat_map(|s| s.action)),
            Column::Img => steps.iter().flat_map(|s| s.rgb.iter().copied()).collect(),
            Column::Depth => floats(&mut steps.iter().flat_map(|s| s.depth_m.iter().copied())),
            Column::Other(i) => (steps.iter())
                .flat_map(|s| match s.other.get(i) {
                    Some(FeatureValue::Float32(v)) => {
                        v.iter().flat_map(|x| x.to_le_bytes()).collect()
                    }
                    Some(FeatureValue::Float64(v)) => {
                        v.iter().flat_map(|x| x.to_le_bytes()).collect()
                    }
                    Some(FeatureValue::Int64(v)) => {
                        v.iter().flat_map(|x| x.to_le_bytes()).collect()
                    }
                    _ => Vec::new(),
                })
                .collect(),
        }
    }
}

impl ZarrStore {
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
            loading: None,
            depth: "Stored (with `--zarr-images`) as float32 metres in `data/depth`.",
            video: Vec::new(),
        }
    }

    fn run_options(info: &DatasetInfo, options: &ZarrOptions) -> Result<RunOptions, ExportError> {
        if info.has(FeatureKind::Depth) {
            options.cloud.options(info)?;
        }
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
        let (columns, mut arrays): (Vec<Column>, Vec<ArrayWriter>) =
            Column::of(info, &options)?.into_iter().unzip();
        if !state.arrays.is_empty() {
            arrays = arrays
                .into_iter()
                .zip(&state.arrays)
                .map(|(array, mark)| array.resume(dir, mark))
                .collect::<Result<_, _>>()?;
        }
        Ok(ZarrStore {
            arrays,
            columns,
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
        let steps = &episode.steps;
        for (array, column) in self.arrays.iter_mut().zip(&self.columns) {
            let expected = array.row_bytes() * steps.len();
            let bytes = column.bytes(steps, &clouds);
            if bytes.len() != expected {
                return Err(ExportError::InvalidEpisode(format!(
                    "episode {}: {} bytes for {}, not {expected}",
                    episode.meta.index,
                    bytes.len(),
                    array.name()
                )));
            }
            array.push(dir, &bytes)?;
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
        if info.has(FeatureKind::Depth) {
            attributes["point_cloud"] = self.options.cloud.describe(info)?;
            attributes["point_cloud"]["channels"] = if self.options.mask_channel {
                json!(["x", "y", "z", "r", "g", "b", "mask_id"])
            } else {
                json!(["x", "y", "z", "r", "g", "b"])
            };
        }
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
        if !info.has(FeatureKind::Depth) {
            return Ok(Vec::new());
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::FeatureSpec;

    fn vector(name: &str, dtype: Dtype) -> FeatureSpec {
        FeatureSpec {
            name: name.into(),
            dtype,
            shape: vec![3],
            names: Vec::new(),
            kind: FeatureKind::Other,
            video: None,
            info: Default::default(),
        }
    }

    #[test]
    fn another_tools_vectors_get_dp3_names_their_keys_and_never_one_array_twice() {
        let mut info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 10, "", Vec::new());
        info.features = vec![
            vector("observation.state", Dtype::Float32),
            vector("action", Dtype::Float64),
            vector("observation.effort", Dtype::Int64),
        ];
        let arrays = Column::of(&info, &ZarrOptions::default()).expect("arrays");
        let named: Vec<(&str, &str)> = arrays.iter().map(|(_, a)| (a.name(), a.dtype())).collect();
        assert_eq!(
            named,
            [
                ("data/state", "<f4"),
                ("data/action", "<f8"),
                ("data/observation.effort", "<i8"),
                ("data/img", "|u1"),
            ]
        );
        info.features.push(vector("state", Dtype::Float32));
        let error = Column::of(&info, &ZarrOptions::default())
            .err()
            .expect("refused");
        assert!(error.to_string().contains("data/state"), "{error}");
        info.features[3] = vector("..", Dtype::Float32);
        assert!(
            Column::of(&info, &ZarrOptions::default()).is_err(),
            "no path outside data/"
        );
    }
}
