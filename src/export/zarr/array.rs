//! A zarr v2 array written row by row (rows along the first axis), our own writer: the `zarrs`
//! crate builds only v3 arrays through its builder, and DP3's readers use zarr 2. A v2 array is
//! a `.zarray` JSON and one file per chunk, named by chunk indices joined with '.', each a zstd
//! frame (level 3, with its content size, which older numcodecs needs) of the chunk's C-order
//! bytes; edge chunks are stored full size, padded with the fill value 0.

use crate::export::dir::DatasetDir;
use crate::export::error::ExportError;
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Rows per chunk along the first axis (DP3's convention).
pub const CHUNK_ROWS: usize = 100;
const ZSTD_LEVEL: i32 = 3;

/// Where an array stands at a checkpoint: its rows so far, and the CRC-32C of the rows of its
/// partial chunk. That chunk is on disk too, and may have been rewritten (filled further) after
/// the checkpoint: its first rows are the same bytes, which a resume reads back and checks.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArrayMark {
    pub rows: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub partial_crc32c: Option<u32>,
}

/// An array being written.
pub struct ArrayWriter {
    /// Folder relative to the store root, e.g. "data/point_cloud".
    path: String,
    /// numpy's dtype string, e.g. "<f4".
    dtype: &'static str,
    /// The shape of one row.
    row_shape: Vec<usize>,
    row_bytes: usize,
    /// Rows of the current chunk.
    buffer: Vec<u8>,
    rows: u64,
}

fn zstd_error(path: &str) -> impl FnOnce(std::io::Error) -> ExportError + '_ {
    move |source| ExportError::Encode {
        what: format!("zstd chunk of {path}"),
        source: Box::new(source),
    }
}

impl ArrayWriter {
    pub fn new(path: &str, dtype: &'static str, item_bytes: usize, row_shape: &[usize]) -> Self {
        let row_bytes = item_bytes * row_shape.iter().product::<usize>();
        ArrayWriter {
            path: path.to_string(),
            dtype,
            row_shape: row_shape.to_vec(),
            row_bytes,
            buffer: Vec::with_capacity(row_bytes * CHUNK_ROWS),
            rows: 0,
        }
    }

    /// The array again at `mark`, its partial chunk read back from the store.
    pub fn resume(mut self, dir: &DatasetDir, mark: &ArrayMark) -> Result<Self, ExportError> {
        self.rows = mark.rows;
        let pending = (mark.rows % CHUNK_ROWS as u64) as usize;
        if pending > 0 {
            let relative = self.chunk_path(mark.rows / CHUNK_ROWS as u64);
            let path = dir.path(&relative);
            let compressed = crate::files::read_regular(&path).map_err(ExportError::io(&path))?;
            let bytes = zstd::bulk::decompress(&compressed, self.row_bytes * CHUNK_ROWS).map_err(
                |source| ExportError::Damaged {
                    path: path.clone(),
                    problem: format!("is not a zstd chunk ({source})"),
                },
            )?;
            let rows = bytes.get(..pending * self.row_bytes).unwrap_or_default();
            if rows.len() != pending * self.row_bytes
                || mark
                    .partial_crc32c
                    .is_some_and(|crc| crc != crc32c::crc32c(rows))
            {
                return Err(ExportError::Damaged {
                    path,
                    problem: format!(
                        "does not hold the {pending} rows the checkpoint recorded (their CRC-32C differs)"
                    ),
                });
            }
            self.buffer = rows.to_vec();
        }
        Ok(self)
    }

    /// Bytes of one row (one frame).
    pub fn row_bytes(&self) -> usize {
        self.row_bytes
    }

    /// numpy's dtype string of its items, e.g. `<f4`.
    pub fn dtype(&self) -> &'static str {
        self.dtype
    }

    /// The array's path in the store, e.g. `data/state`.
    pub fn name(&self) -> &str {
        &self.path
    }

    pub fn mark(&self) -> ArrayMark {
        ArrayMark {
            rows: self.rows,
            partial_crc32c: (!self.buffer.is_empty()).then(|| crc32c::crc32c(&self.buffer)),
        }
    }

    /// The partial chunk's path, if the array has one (a checkpoint writes it, and the chunk is
    /// rewritten when it fills).
    pub fn partial_chunk(&self) -> Option<String> {
        (!self.buffer.is_empty()).then(|| self.chunk_path(self.rows / CHUNK_ROWS as u64))
    }

    fn chunk_path(&self, chunk: u64) -> String {
        let zeros = ".0".repeat(self.row_shape.len());
        format!("{}/{chunk}{zeros}", self.path)
    }

    /// Appends rows (a whole number of rows' bytes), writing each chunk that fills.
    pub fn push(&mut self, dir: &mut DatasetDir, mut bytes: &[u8]) -> Result<u64, ExportError> {
        if !bytes.len().is_multiple_of(self.row_bytes) {
            return Err(ExportError::Internal(format!(
                "{} takes rows of {} bytes, not {}",
                self.path,
                self.row_bytes,
                bytes.len()
            )));
        }
        let mut written = 0;
        while !bytes.is_empty() {
            let room = self.row_bytes * CHUNK_ROWS - self.buffer.len();
            let (now, rest) = bytes.split_at(room.min(bytes.len()));
            self.buffer.extend_from_slice(now);
            self.rows += (now.len() / self.row_bytes) as u64;
            bytes = rest;
            if self.buffer.len() == self.row_bytes * CHUNK_ROWS {
                written += self.write_chunk(dir)?;
                self.buffer.clear();
            }
        }
        Ok(written)
    }

    /// Writes the chunk being filled (padded with zeros to full size); returns its size.
    fn write_chunk(&self, dir: &mut DatasetDir) -> Result<u64, ExportError> {
        let chunk = (self.rows - 1) / CHUNK_ROWS as u64;
        let mut full = self.buffer.clone();
        full.resize(self.row_bytes * CHUNK_ROWS, 0);
        let compressed = zstd::bulk::compress(&full, ZSTD_LEVEL).map_err(zstd_error(&self.path))?;
        dir.write_atomically(&self.chunk_path(chunk), &compressed)
    }

    /// Writes the partial chunk, if any (at a checkpoint, and at the end).
    pub fn flush(&self, dir: &mut DatasetDir) -> Result<u64, ExportError> {
        if self.buffer.is_empty() {
            Ok(0)
        } else {
            self.write_chunk(dir)
        }
    }

    /// Writes `.zarray` with the final shape; returns its size.
    pub fn write_metadata(&self, dir: &mut DatasetDir) -> Result<u64, ExportError> {
        let mut shape = vec![self.rows as usize];
        shape.extend(&self.row_shape);
        let mut chunks = vec![CHUNK_ROWS];
        chunks.extend(&self.row_shape);
        let fill = if self.dtype.ends_with("f4") {
            json!(0.0)
        } else {
            json!(0)
        };
        let zarray = json!({
            "chunks": chunks,
            "compressor": {"id": "zstd", "level": ZSTD_LEVEL},
            "dimension_separator": ".",
            "dtype": self.dtype,
            "fill_value": fill,
            "filters": null,
            "order": "C",
            "shape": shape,
            "zarr_format": 2,
        });
        let relative = format!("{}/.zarray", self.path);
        let bytes = serde_json::to_vec_pretty(&zarray).map_err(|source| ExportError::Json {
            path: dir.path(&relative),
            source,
        })?;
        dir.write_atomically(&relative, &bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::dir::RunOptions;

    fn rows(from: u32, to: u32) -> Vec<u8> {
        (from..to)
            .flat_map(|r| [r as f32, -(r as f32)])
            .flat_map(f32::to_le_bytes)
            .collect()
    }

    /// Writes 250 rows, stopping (with a checkpoint's flush) after `stop` of them when given.
    fn write(root: &std::path::Path, stop: Option<u32>) -> Vec<(String, Vec<u8>)> {
        std::fs::remove_dir_all(root).ok();
        let mut dir = DatasetDir::create(root, &RunOptions::default()).expect("create");
        let mut array = ArrayWriter::new("data/x", "<f4", 4, &[2]);
        let first = stop.unwrap_or(250);
        array.push(&mut dir, &rows(0, first)).expect("push");
        if stop.is_some() {
            array.flush(&mut dir).expect("flush");
            let mark = array.mark();
            // A new writer picks the partial chunk up from the store.
            array = ArrayWriter::new("data/x", "<f4", 4, &[2])
                .resume(&dir, &mark)
                .expect("resume");
            array.push(&mut dir, &rows(first, 250)).expect("push");
        }
        array.flush(&mut dir).expect("flush");
        array.write_metadata(&mut dir).expect("metadata");
        let mut files: Vec<(String, Vec<u8>)> = ["0.0", "1.0", "2.0", ".zarray"]
            .iter()
            .map(|name| {
                let path = root.join("data/x").join(name);
                (name.to_string(), std::fs::read(&path).expect("chunk"))
            })
            .collect();
        files.sort();
        files
    }

    #[test]
    fn chunks_are_zstd_frames_padded_to_full_size_and_resume_continues_a_partial_one() {
        let root = std::env::temp_dir().join(format!("surgvla-zarr-{}", std::process::id()));
        let whole = write(&root, None);
        let chunk = &whole
            .iter()
            .find(|(n, _)| n == "2.0")
            .expect("edge chunk")
            .1;
        let bytes = zstd::bulk::decompress(chunk, 8 * CHUNK_ROWS).expect("zstd");
        assert_eq!(
            bytes.len(),
            8 * CHUNK_ROWS,
            "edge chunks are stored full size"
        );
        assert_eq!(&bytes[..8 * 50], &rows(200, 250)[..]);
        assert!(
            bytes[8 * 50..].iter().all(|&b| b == 0),
            "padded with the fill value"
        );
        assert_eq!(
            zstd::zstd_safe::get_frame_content_size(chunk).expect("a frame"),
            Some((8 * CHUNK_ROWS) as u64),
            "the frame records its content size"
        );
        for stop in [30, 100, 170] {
            assert_eq!(write(&root, Some(stop)), whole, "stopped after {stop} rows");
        }
        let zarray = String::from_utf8(whole[0].1.clone()).expect("json");
        assert!(
            zarray.contains("\"shape\": [\n    250,\n    2\n  ]"),
            "{zarray}"
        );
        std::fs::remove_dir_all(&root).ok();
    }
}
