//! Reading a LeRobot v3.0 dataset back (surgvla's own round trips and validation; interop is
//! proven with the real lerobot loader in `tests/interop/`).

use crate::export::ExportError;
use arrow_array::{
    Array, BinaryArray, FixedSizeListArray, Float32Array, Int64Array, RecordBatch, StructArray,
};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use std::fs::File;
use std::path::{Path, PathBuf};

/// One frame as stored.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredFrame {
    pub index: i64,
    pub episode_index: i64,
    pub frame_index: i64,
    pub task_index: i64,
    pub timestamp: f32,
    pub state: Vec<f32>,
    pub action: Vec<f32>,
    pub environment_state: Vec<f32>,
    /// Encoded image bytes by feature key.
    pub images: Vec<(String, Vec<u8>)>,
}

/// Reads every record batch of a parquet file.
pub fn read_parquet(path: &Path) -> Result<Vec<RecordBatch>, ExportError> {
    let file = File::open(path).map_err(ExportError::io(path))?;
    let parquet_error = |source| ExportError::Parquet {
        path: path.to_path_buf(),
        source,
    };
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .map_err(parquet_error)?
        .build()
        .map_err(parquet_error)?;
    reader
        .map(|batch| batch.map_err(ExportError::Arrow))
        .collect()
}

/// The value of a schema metadata key of a parquet file (e.g. "pandas").
pub fn schema_metadata(path: &Path, key: &str) -> Result<Option<String>, ExportError> {
    let file = File::open(path).map_err(ExportError::io(path))?;
    let builder =
        ParquetRecordBatchReaderBuilder::try_new(file).map_err(|source| ExportError::Parquet {
            path: path.to_path_buf(),
            source,
        })?;
    if let Some(value) = builder.schema().metadata().get(key) {
        return Ok(Some(value.clone()));
    }
    let pairs = builder.metadata().file_metadata().key_value_metadata();
    Ok(pairs.and_then(|kv| {
        kv.iter()
            .find(|p| p.key == key)
            .and_then(|p| p.value.clone())
    }))
}

/// The data files in path order.
pub fn data_files(root: &Path) -> Result<Vec<PathBuf>, ExportError> {
    let data = root.join("data");
    let mut files = Vec::new();
    let chunks = std::fs::read_dir(&data).map_err(ExportError::io(&data))?;
    for chunk in chunks {
        let chunk = chunk.map_err(ExportError::io(&data))?.path();
        for file in std::fs::read_dir(&chunk).map_err(ExportError::io(&chunk))? {
            let file = file.map_err(ExportError::io(&chunk))?.path();
            if file.extension().is_some_and(|e| e == "parquet")
                && !file
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            {
                files.push(file);
            }
        }
    }
    files.sort();
    Ok(files)
}

fn column<'a, T: 'static>(
    batch: &'a RecordBatch,
    name: &str,
    path: &Path,
) -> Result<&'a T, ExportError> {
    batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<T>())
        .ok_or_else(|| {
            ExportError::InvalidEpisode(format!(
                "{}: column {name} missing or of the wrong type",
                path.display()
            ))
        })
}

fn vector(list: &FixedSizeListArray, row: usize) -> Vec<f32> {
    let values = list.value(row);
    values
        .as_any()
        .downcast_ref::<Float32Array>()
        .map(|v| v.values().to_vec())
        .unwrap_or_default()
}

/// Reads every frame of the dataset at `root`, in index order.
pub fn read_frames(root: &Path, image_keys: &[&str]) -> Result<Vec<StoredFrame>, ExportError> {
    let mut frames = Vec::new();
    for path in data_files(root)? {
        for batch in read_parquet(&path)? {
            let ints = |name| column::<Int64Array>(&batch, name, &path);
            let (index, episode, frame, task) = (
                ints("index")?,
                ints("episode_index")?,
                ints("frame_index")?,
                ints("task_index")?,
            );
            let timestamp = column::<Float32Array>(&batch, "timestamp", &path)?;
            let state = column::<FixedSizeListArray>(&batch, "observation.state", &path)?;
            let action = column::<FixedSizeListArray>(&batch, "action", &path)?;
            let environment =
                column::<FixedSizeListArray>(&batch, "observation.environment_state", &path)?;
            let images: Vec<(&str, &StructArray)> = image_keys
                .iter()
                .map(|k| column::<StructArray>(&batch, k, &path).map(|c| (*k, c)))
                .collect::<Result<_, _>>()?;
            for row in 0..batch.num_rows() {
                let mut encoded = Vec::new();
                for (key, images) in &images {
                    let bytes = images
                        .column_by_name("bytes")
                        .and_then(|c| c.as_any().downcast_ref::<BinaryArray>())
                        .ok_or_else(|| {
                            ExportError::InvalidEpisode(format!(
                                "{}: {key} has no bytes",
                                path.display()
                            ))
                        })?;
                    encoded.push((key.to_string(), bytes.value(row).to_vec()));
                }
                frames.push(StoredFrame {
                    index: index.value(row),
                    episode_index: episode.value(row),
                    frame_index: frame.value(row),
                    task_index: task.value(row),
                    timestamp: timestamp.value(row),
                    state: vector(state, row),
                    action: vector(action, row),
                    environment_state: vector(environment, row),
                    images: encoded,
                });
            }
        }
    }
    Ok(frames)
}
