//! The DP3 zarr store's merge: chunks span episodes, so every array is re-packed. Each
//! input's chunks are read in order, decompressed, cut to its rows and pushed through a new
//! [`ArrayWriter`] per array, which writes full chunks as they fill, exactly as one run writes
//! them; `meta/episode_ends` gets each input's ends offset by the frames before it; `.zattrs`
//! is the first input's with the merged collection. Points are not sampled again: the merged
//! store holds the inputs' arrays bit for bit, and N of N merged are the single run's bytes.
//!
//! Every input is checked before anything is written: the same arrays, dtypes and row shapes,
//! our chunking and codec, and episode ends that agree with the arrays' lengths. A zarr merge
//! resumes by starting over in its folder ([`crate::export::merge::output_dir`]).

use super::array::{ArrayWriter, CHUNK_ROWS};
use super::writer::MANIFEST;
use crate::export::bounded::read_json;
use crate::export::bounded::{read_capped, read_metadata};
use crate::export::collection::Collection;
use crate::export::convert::ConvertError;
use crate::export::dir::DatasetDir;
use crate::export::error::ExportError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::merge::{Part, finish_folder, plan};
use crate::export::sink::Summary;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// The arrays of a store, in the order the writer makes them.
const DATA_ARRAYS: [&str; 5] = [
    "data/point_cloud",
    "data/state",
    "data/action",
    "data/img",
    "data/depth",
];
const EPISODE_ENDS: &str = "meta/episode_ends";

/// One array of one input, as its `.zarray` says.
#[derive(Clone, Debug, PartialEq)]
struct ArrayShape {
    dtype: &'static str,
    item_bytes: usize,
    row_shape: Vec<usize>,
    rows: u64,
}

impl ArrayShape {
    fn row_bytes(&self) -> usize {
        self.item_bytes * self.row_shape.iter().product::<usize>()
    }
}

fn invalid(path: &Path, problem: impl Into<String>) -> MergeError {
    MergeError::Convert(ConvertError::Read(ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: problem.into(),
    }))
}

fn read_error(error: ExportError) -> MergeError {
    MergeError::Convert(ConvertError::Read(error))
}

fn write_error(error: ExportError) -> MergeError {
    MergeError::Convert(ConvertError::Write(error))
}

/// Reads an array's `.zarray`, refusing what our writer does not write.
fn array_shape(root: &Path, array: &str) -> Result<ArrayShape, MergeError> {
    let path = root.join(array).join(".zarray");
    let bytes = read_metadata(&path).map_err(read_error)?;
    let zarray: Value =
        serde_json::from_slice(&bytes).map_err(|e| invalid(&path, format!("is not JSON: {e}")))?;
    let (dtype, item_bytes) = match zarray["dtype"].as_str() {
        Some("<f4") => ("<f4", 4),
        Some("|u1") => ("|u1", 1),
        Some("<i8") => ("<i8", 8),
        Some("<f8") => ("<f8", 8),
        other => {
            return Err(invalid(
                &path,
                format!("dtype {other:?} is not one surgvla writes"),
            ));
        }
    };
    let numbers = |key: &str| -> Option<Vec<usize>> {
        zarray[key]
            .as_array()?
            .iter()
            .map(|v| v.as_u64().and_then(|n| usize::try_from(n).ok()))
            .collect()
    };
    let (Some(shape), Some(chunks)) = (numbers("shape"), numbers("chunks")) else {
        return Err(invalid(&path, "has no shape or chunks"));
    };
    let compressor = &zarray["compressor"]["id"];
    let chunked = chunks.first() == Some(&CHUNK_ROWS) && chunks[1..] == shape[1..];
    let separator = &zarray["dimension_separator"];
    let dotted = separator.is_null() || separator == ".";
    if shape.is_empty()
        || !chunked
        || compressor != "zstd"
        || !zarray["filters"].is_null()
        || !dotted
    {
        return Err(invalid(
            &path,
            format!(
                "is not chunked as surgvla writes ({CHUNK_ROWS} rows a chunk, zstd, no filters, \
                 chunk keys joined by '.')"
            ),
        ));
    }
    let array = ArrayShape {
        dtype,
        item_bytes,
        row_shape: shape[1..].to_vec(),
        rows: shape[0] as u64,
    };
    // A chunk is decompressed whole: its size is checked before anything is allocated, with
    // the cap validate uses.
    let chunk_bytes = array
        .row_shape
        .iter()
        .try_fold(item_bytes * CHUNK_ROWS, |a, &b| a.checked_mul(b));
    if chunk_bytes.is_none_or(|b| b > super::check::MAX_CHUNK_BYTES) {
        return Err(invalid(&path, "has chunks over the 256 MiB accepted"));
    }
    Ok(array)
}

/// Chunk `index` of an array, decompressed and cut to its rows.
fn chunk_rows(
    root: &Path,
    array: &str,
    shape: &ArrayShape,
    index: u64,
) -> Result<Vec<u8>, MergeError> {
    let zeros = ".0".repeat(shape.row_shape.len());
    let path = root.join(format!("{array}/{index}{zeros}"));
    let full = shape.row_bytes() * CHUNK_ROWS;
    // zstd's worst case for incompressible data is a little over the input.
    let stored = read_capped(&path, (full + full / 64 + 1024) as u64).map_err(read_error)?;
    let mut bytes = zstd::bulk::decompress(&stored, full + 1)
        .map_err(|e| invalid(&path, format!("is not a zstd chunk: {e}")))?;
    if bytes.len() != full {
        return Err(invalid(
            &path,
            format!("holds {} bytes, not {full}", bytes.len()),
        ));
    }
    let rows = (shape.rows - index * CHUNK_ROWS as u64).min(CHUNK_ROWS as u64) as usize;
    bytes.truncate(rows * shape.row_bytes());
    Ok(bytes)
}

/// One input store: its root, arrays and episode ends.
struct Store {
    root: PathBuf,
    arrays: Vec<(&'static str, ArrayShape)>,
    ends: Vec<i64>,
    attributes: Value,
}

fn open(root: &Path) -> Result<Store, MergeError> {
    let attributes = read_json(&root.join(".zattrs")).map_err(read_error)?;
    let mut arrays = Vec::new();
    for array in DATA_ARRAYS {
        if root.join(array).join(".zarray").is_file() {
            arrays.push((array, array_shape(root, array)?));
        }
    }
    let ends_shape = array_shape(root, EPISODE_ENDS)?;
    let ends_path = root.join(EPISODE_ENDS);
    if ends_shape.dtype != "<i8" || !ends_shape.row_shape.is_empty() {
        return Err(invalid(&ends_path, "is not a list of int64 episode ends"));
    }
    let ends = ends_of(root, &ends_shape)?;
    let frames = ends.last().copied().unwrap_or(0);
    let increasing = ends.windows(2).all(|w| w[0] < w[1]) && ends.first().is_none_or(|&e| e > 0);
    if !increasing {
        return Err(invalid(
            &ends_path,
            "episode ends do not increase from above 0",
        ));
    }
    for (array, shape) in &arrays {
        if shape.rows as i64 != frames {
            return Err(invalid(
                &root.join(array),
                format!(
                    "has {} rows, but the episodes end at frame {frames}",
                    shape.rows
                ),
            ));
        }
    }
    Ok(Store {
        root: root.to_path_buf(),
        arrays,
        ends,
        attributes,
    })
}

/// `meta/episode_ends`: one int64 per episode, in chunks of [`CHUNK_ROWS`].
fn ends_of(root: &Path, shape: &ArrayShape) -> Result<Vec<i64>, MergeError> {
    let mut ends = Vec::new();
    for index in 0..shape.rows.div_ceil(CHUNK_ROWS as u64) {
        let bytes = chunk_rows(root, EPISODE_ENDS, shape, index)?;
        ends.extend(
            bytes
                .chunks_exact(8)
                .map(|b| i64::from_le_bytes(b.try_into().unwrap_or_default())),
        );
    }
    Ok(ends)
}

/// Refuses stores whose arrays differ from the first's (names, dtypes or row shapes).
fn same_arrays(ordered: &[&Store]) -> Result<(), MergeError> {
    let names = |s: &Store| -> Vec<(&str, Vec<usize>, &str)> {
        s.arrays
            .iter()
            .map(|(a, x)| (*a, x.row_shape.clone(), x.dtype))
            .collect()
    };
    let Some(first) = ordered.first() else {
        return Err(MergeError::NoInput);
    };
    for store in &ordered[1..] {
        if names(store) != names(first) {
            return Err(MergeError::Incompatible {
                path: store.root.clone(),
                first: first.root.clone(),
                reasons: "its arrays differ (names, dtypes or row shapes)".into(),
            });
        }
    }
    Ok(())
}

/// The merged store's groups and attributes (the first store's, with the merged collection).
fn write_groups(
    dir: &mut DatasetDir,
    first: &Store,
    plan: &crate::export::merge::Plan,
) -> Result<(), MergeError> {
    let mut attributes = first.attributes.clone();
    if let Some(collection) = &plan.collection {
        attributes["surgvla"]["collection"] = collection.to_json();
    }
    let group = json!({"zarr_format": 2});
    let files = [
        (".zgroup", group.clone()),
        ("data/.zgroup", group.clone()),
        ("meta/.zgroup", group),
        (".zattrs", attributes),
    ];
    for (relative, value) in files {
        let bytes = serde_json::to_vec_pretty(&value).map_err(|source| {
            write_error(ExportError::Json {
                path: dir.path(relative),
                source,
            })
        })?;
        dir.write_atomically(relative, &bytes)
            .map_err(write_error)?;
    }
    Ok(())
}

/// Merges the request's zarr stores into a new one at its `out` (see the module overview).
pub(super) fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let mut stores = Vec::new();
    let mut parts = Vec::new();
    for path in request.inputs {
        let store = open(path)?;
        let collection = Collection::from_json(&store.attributes["surgvla"]["collection"]);
        parts.push(Part::read(path, &path.join(MANIFEST), collection)?);
        stores.push(store);
    }
    let plan = plan(parts)?;
    let ordered: Vec<&Store> = plan
        .parts
        .iter()
        .filter_map(|p| stores.iter().find(|s| s.root == p.path))
        .collect();
    let first = ordered.first().ok_or(MergeError::NoInput)?;
    same_arrays(&ordered)?;
    let mut dir = crate::export::merge::output_dir(request.out, request.resume, &plan.options)
        .map_err(write_error)?;
    let mut writers: Vec<ArrayWriter> = first
        .arrays
        .iter()
        .map(|(array, shape)| {
            ArrayWriter::new(array, shape.dtype, shape.item_bytes, &shape.row_shape)
        })
        .collect();
    let mut ends: Vec<i64> = Vec::new();
    for store in &ordered {
        for ((array, shape), writer) in store.arrays.iter().zip(&mut writers) {
            for index in 0..shape.rows.div_ceil(CHUNK_ROWS as u64) {
                let rows = chunk_rows(&store.root, array, shape, index)?;
                writer.push(&mut dir, &rows).map_err(write_error)?;
            }
        }
        let before = ends.last().copied().unwrap_or(0);
        ends.extend(store.ends.iter().map(|e| e + before));
        (request.progress)(ends.len() as u64);
    }
    let mut end_writer = ArrayWriter::new(EPISODE_ENDS, "<i8", 8, &[]);
    let end_bytes: Vec<u8> = ends.iter().flat_map(|e| e.to_le_bytes()).collect();
    end_writer.push(&mut dir, &end_bytes).map_err(write_error)?;
    for writer in writers.iter().chain([&end_writer]) {
        writer.flush(&mut dir).map_err(write_error)?;
        writer.write_metadata(&mut dir).map_err(write_error)?;
    }
    write_groups(&mut dir, first, &plan)?;
    if let Some(card) = crate::export::merge::merged_card(&plan)? {
        dir.write_atomically(crate::export::card::CARD, &card)
            .map_err(write_error)?;
    }
    let roots: Vec<&Path> = ordered.iter().map(|s| s.root.as_path()).collect();
    let frames = ends.last().copied().unwrap_or(0) as u64;
    finish_folder(dir, MANIFEST, (ends.len() as u64, frames), &roots, &plan)
}
