//! Validating a DP3 zarr v2 store (ours or another writer's): the root group, every array's
//! `.zarray` (zarr v2, C order, a compressor we can decode: zstd or none), every chunk present
//! and decoding to the chunk's size, `meta/episode_ends` strictly increasing and ending at the
//! length of every `data/` array, point clouds shaped (T, N, 6 or 7), and no NaN or Inf in float
//! arrays (every chunk; `quick` reads the metadata and the first chunk of each array).

use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::collection::Collection;
use crate::export::findings::{At, FeatureFact, Findings, ValidateOptions, check_manifest};
use crate::export::schema;
use rayon::prelude::*;
use serde_json::Value;
use std::path::Path;

/// An array's metadata as `.zarray` gives it.
struct ArrayMeta {
    name: String,
    shape: Vec<usize>,
    chunks: Vec<usize>,
    dtype: String,
    item_bytes: usize,
    zstd: bool,
    /// What joins a chunk key's indices: `.` (flat) or `/` (nested folders).
    separator: &'static str,
}

/// The largest chunk decoded, in bytes (ours are a few MB).
pub(super) const MAX_CHUNK_BYTES: usize = 256 << 20;

/// Bytes per item of `.zarray`'s dtype (`<f4` -> 4; 0 when not a numpy type string).
fn item_bytes_of(meta: &Value) -> usize {
    let dtype = meta["dtype"].as_str().unwrap_or_default();
    dtype.get(2..).and_then(|n| n.parse().ok()).unwrap_or(0)
}

/// Whether the sizes `.zarray` claims (`shape`, `chunks`) are what surgvla reads: a chunk within
/// [`MAX_CHUNK_BYTES`], and no more chunks than the folder's files could be (each a finding
/// otherwise). Checked before anything is allocated or counted from them.
fn sizes_fit(
    root: &Path,
    name: &str,
    meta: &Value,
    (shape, chunks): (&[usize], &[usize]),
    findings: &Findings,
) -> bool {
    let path = root.join(name).join(".zarray");
    let chunk_bytes = chunks
        .iter()
        .chain([&item_bytes_of(meta)])
        .try_fold(1usize, |total, n| total.checked_mul(*n));
    if chunk_bytes.is_none_or(|b| b > MAX_CHUNK_BYTES) {
        findings.file_error(
            &path,
            Check::Schema,
            format!(
                "chunks {chunks:?} are larger than the {} MiB surgvla reads",
                MAX_CHUNK_BYTES >> 20
            ),
        );
        return false;
    }
    let grid = shape.iter().zip(chunks).map(|(s, c)| s.div_ceil(*c));
    let claimed = grid
        .clone()
        .try_fold(1usize, |total, n| total.checked_mul(n));
    let present = std::fs::read_dir(root.join(name)).map_or(0, |entries| entries.count());
    // A few missing chunks are reported one by one below; a shape claiming far more chunks
    // than there are files is reported once (counting them would not end).
    if claimed.is_none_or(|n| n > 2 * present + 64) {
        findings.file_error(
            &path,
            Check::Chunk,
            format!(
                "shape {shape:?} in chunks of {chunks:?} needs {} chunks; the folder holds {present} files",
                claimed.map_or("more than 2^64".to_string(), |n| n.to_string())
            ),
        );
        return false;
    }
    true
}

fn array_meta(root: &Path, name: &str, findings: &Findings) -> Option<ArrayMeta> {
    let path = root.join(name).join(".zarray");
    let Ok(meta) = read_json(&path) else {
        findings.file_error(&path, Check::Present, "is missing or not JSON");
        return None;
    };
    let numbers = |key: &str| -> Option<Vec<usize>> {
        meta[key]
            .as_array()?
            .iter()
            .map(|v| v.as_u64().map(|v| v as usize))
            .collect()
    };
    let (Some(shape), Some(chunks)) = (numbers("shape"), numbers("chunks")) else {
        findings.file_error(&path, Check::Schema, "lacks shape or chunks");
        return None;
    };
    if meta["zarr_format"] != 2 {
        findings.file_error(
            &path,
            Check::Schema,
            format!("zarr_format is {}, not 2", meta["zarr_format"]),
        );
    }
    if shape.len() != chunks.len() || chunks.contains(&0) {
        findings.file_error(
            &path,
            Check::Schema,
            format!("chunks {chunks:?} do not fit shape {shape:?}"),
        );
        return None;
    }
    if !sizes_fit(root, name, &meta, (&shape, &chunks), findings) {
        return None;
    }
    if meta["order"] != "C" {
        findings.file_error(&path, Check::Schema, "order is not C");
    }
    let dtype = meta["dtype"].as_str().unwrap_or_default().to_string();
    let item_bytes = item_bytes_of(&meta);
    if item_bytes == 0 {
        findings.file_error(
            &path,
            Check::Schema,
            format!("dtype {dtype:?} is not a numpy type string"),
        );
        return None;
    }
    let (zstd, separator) = match codec_of(&meta) {
        Ok(codec) => codec,
        Err(problem) => {
            findings.file_error(&path, Check::Schema, problem);
            return None;
        }
    };
    Some(ArrayMeta {
        name: name.into(),
        shape,
        chunks,
        dtype,
        item_bytes,
        zstd,
        separator,
    })
}

/// How an array's chunks are stored, as far as surgvla reads them: (zstd or not, the chunk
/// key's separator); an error for a compressor it does not decode, a separator that is not
/// `.` or `/`, or filters (which change the bytes before the compressor; surgvla applies none).
fn codec_of(meta: &Value) -> Result<(bool, &'static str), String> {
    let zstd = match &meta["compressor"] {
        Value::Null => false,
        c if c["id"] == "zstd" => true,
        c => {
            return Err(format!(
                "compressor {} is not one surgvla decodes (zstd or none)",
                c["id"]
            ));
        }
    };
    let separator = match &meta["dimension_separator"] {
        Value::Null => ".",
        s if s == "." => ".",
        s if s == "/" => "/",
        other => return Err(format!("dimension_separator {other} is not '.' or '/'")),
    };
    match &meta["filters"] {
        Value::Null => Ok((zstd, separator)),
        Value::Array(filters) if filters.is_empty() => Ok((zstd, separator)),
        filters => Err(format!(
            "filters {filters} are not applied by surgvla, so its chunks cannot be checked"
        )),
    }
}

/// Checks every chunk of `array` (only the first when `quick`).
fn check_chunks(root: &Path, array: &ArrayMeta, quick: bool, findings: &Findings) {
    let grid: Vec<usize> = array
        .shape
        .iter()
        .zip(&array.chunks)
        .map(|(s, c)| s.div_ceil(*c))
        .collect();
    let count: usize = grid.iter().product();
    let limit = if quick { count.min(1) } else { count };
    (0..limit)
        .into_par_iter()
        .for_each(|linear| check_chunk(root, array, &chunk_key(linear, &grid), findings));
}

/// The key (index per axis) of the chunk at row-major position `linear` of `grid`.
fn chunk_key(linear: usize, grid: &[usize]) -> Vec<usize> {
    let mut rest = linear;
    let mut key = vec![0usize; grid.len()];
    for (axis, size) in grid.iter().enumerate().rev() {
        key[axis] = rest % size;
        rest /= size;
    }
    key
}

/// One chunk: present, decoding to a whole chunk's bytes, its floats finite (in the rows the
/// array's shape covers).
fn check_chunk(root: &Path, array: &ArrayMeta, key: &[usize], findings: &Findings) {
    let name = key
        .iter()
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(array.separator);
    let name = if name.is_empty() {
        "0".to_string()
    } else {
        name
    };
    let path = root.join(&array.name).join(&name);
    let at = || At::file(findings.relative(&path));
    let chunk_bytes = array.chunks.iter().product::<usize>() * array.item_bytes;
    let Ok(stored) = crate::export::bounded::read_capped(&path, MAX_CHUNK_BYTES as u64 * 2) else {
        findings.error(at(), Check::Present, "chunk is missing");
        return;
    };
    let bytes = if array.zstd {
        // Decoded into at most one chunk's bytes (a larger frame is an error, not an allocation).
        match zstd::bulk::decompress(&stored, chunk_bytes + 1) {
            Ok(bytes) => bytes,
            Err(_) => {
                findings.error(at(), Check::Chunk, "is not a zstd frame");
                return;
            }
        }
    } else {
        stored
    };
    if bytes.len() != chunk_bytes {
        findings.error(
            at(),
            Check::Chunk,
            format!(
                "decodes to {} bytes, a chunk of {:?} {} is {chunk_bytes}",
                bytes.len(),
                array.chunks,
                array.dtype
            ),
        );
        return;
    }
    let rows_per_chunk = array.chunks.first().copied().unwrap_or(1);
    let row_bytes = chunk_bytes / rows_per_chunk.max(1);
    let valid_rows = array.shape.first().map_or(0, |t| {
        t.saturating_sub(key.first().copied().unwrap_or(0) * rows_per_chunk)
            .min(rows_per_chunk)
    });
    if let Some(position) = first_non_finite(&bytes[..valid_rows * row_bytes], &array.dtype) {
        let row = key.first().copied().unwrap_or(0) * rows_per_chunk
            + position * array.item_bytes / row_bytes.max(1);
        findings.error(
            at().frame(row as u64),
            Check::Finite,
            format!("{} holds NaN or Inf at row {row}", array.name),
        );
    }
}

/// The position of the first NaN or infinity among little-endian floats of `dtype` (`<f4` or
/// `<f8`; None for any other dtype).
fn first_non_finite(bytes: &[u8], dtype: &str) -> Option<usize> {
    if dtype.ends_with("f4") {
        bytes
            .chunks_exact(4)
            .position(|b| !f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite())
    } else if dtype.ends_with("f8") {
        bytes
            .chunks_exact(8)
            .position(|b| !f64::from_le_bytes(b.try_into().unwrap_or([0; 8])).is_finite())
    } else {
        None
    }
}

/// Reads an int64 1-D array whole.
fn read_ints(root: &Path, array: &ArrayMeta) -> Option<Vec<i64>> {
    let mut values = Vec::new();
    let rows = *array.shape.first()?;
    let per_chunk = *array.chunks.first()?;
    for chunk in 0..rows.div_ceil(per_chunk) {
        let path = root.join(&array.name).join(chunk.to_string());
        let stored = crate::export::bounded::read_capped(&path, MAX_CHUNK_BYTES as u64 * 2).ok()?;
        let chunk_bytes = array.chunks.iter().product::<usize>() * array.item_bytes;
        let bytes = if array.zstd {
            zstd::bulk::decompress(&stored, chunk_bytes + 1).ok()?
        } else {
            stored
        };
        values.extend(
            bytes
                .chunks_exact(8)
                .map(|b| i64::from_le_bytes(b.try_into().unwrap_or([0; 8]))),
        );
    }
    values.truncate(rows);
    Some(values)
}

/// Checks the store at `root`; returns (episodes, frames).
pub fn check(root: &Path, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
    if !root.join(".zgroup").is_file() {
        findings.error(
            At::file(".zgroup"),
            Check::Present,
            "is missing: zarr cannot open the store",
        );
    }
    // Clouds where the store says it has them (a store of another tool's data without depth
    // has none), state and action where surgvla made the episodes.
    let (mut clouds, mut ours) = (true, true);
    if let Ok(attributes) = read_json(&root.join(".zattrs"))
        && let Some(surgvla) = attributes.get("surgvla")
    {
        clouds = surgvla.get("point_cloud").is_some();
        ours = surgvla["generator"].as_str().is_some_and(|g| !g.is_empty());
        findings.learn(|facts| {
            facts.fps = surgvla["fps"].as_f64();
            facts.generator = surgvla["generator"].as_str().map(String::from);
            facts.collection = Collection::from_json(&surgvla["collection"]);
        });
        for (pointer, problem) in schema::check_text(surgvla, schema::SURGVLA_META) {
            findings.error(
                At::file(".zattrs"),
                Check::Schema,
                format!("/surgvla{pointer} {problem}"),
            );
        }
    }
    check_manifest(root, super::writer::MANIFEST, options.quick, findings);
    let data_names: Vec<String> = std::fs::read_dir(root.join("data"))
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.path().join(".zarray").is_file())
        .map(|e| format!("data/{}", e.file_name().to_string_lossy()))
        .collect();
    let required = [
        ("data/point_cloud", clouds),
        ("data/state", ours),
        ("data/action", ours),
    ];
    for required in required
        .iter()
        .filter(|(_, needed)| *needed)
        .map(|(name, _)| *name)
    {
        if !data_names.iter().any(|n| n == required) {
            findings.error(At::file(required), Check::Present, "array is missing");
        }
    }
    let arrays: Vec<ArrayMeta> = data_names
        .iter()
        .filter_map(|n| array_meta(root, n, findings))
        .collect();
    let ends_meta = array_meta(root, "meta/episode_ends", findings);
    findings.learn(|facts| {
        facts.features = arrays
            .iter()
            .map(|a| FeatureFact {
                name: a.name.clone(),
                dtype: a.dtype.clone(),
                shape: a.shape.clone(),
            })
            .collect();
    });
    let frames = check_arrays(root, &arrays, options.quick, findings);
    let episodes = ends_meta.map_or(0, |meta| check_episode_ends(root, &meta, frames, findings));
    (episodes, frames)
}

/// Every data array's chunks and shape (point clouds (T, N, 6 or 7), state and action (T, D)),
/// all with the same number of rows; returns that number (the frames).
fn check_arrays(root: &Path, arrays: &[ArrayMeta], quick: bool, findings: &Findings) -> u64 {
    for array in arrays {
        check_chunks(root, array, quick, findings);
        if array.name == "data/point_cloud"
            && (array.shape.len() != 3 || !matches!(array.shape[2], 6 | 7))
        {
            findings.error(
                At::file("data/point_cloud/.zarray"),
                Check::Shape,
                format!("shape {:?} is not (T, N, 6) or (T, N, 7)", array.shape),
            );
        }
        if matches!(array.name.as_str(), "data/state" | "data/action") && array.shape.len() != 2 {
            findings.error(
                At::file(format!("{}/.zarray", array.name)),
                Check::Shape,
                format!("shape {:?} is not (T, D)", array.shape),
            );
        }
    }
    let frames = arrays
        .first()
        .and_then(|a| a.shape.first())
        .copied()
        .unwrap_or(0) as u64;
    for array in arrays {
        if array.shape.first().copied().unwrap_or(0) as u64 != frames {
            findings.error(
                At::file(format!("{}/.zarray", array.name)),
                Check::Shape,
                format!(
                    "{} rows where {} has {frames}",
                    array.shape[0], arrays[0].name
                ),
            );
        }
    }
    frames
}

/// `meta/episode_ends` strictly increasing and ending at `frames`; returns the episodes.
fn check_episode_ends(root: &Path, meta: &ArrayMeta, frames: u64, findings: &Findings) -> u64 {
    let Some(ends) = read_ints(root, meta) else {
        findings.error(
            At::file("meta/episode_ends"),
            Check::Chunk,
            "cannot be read whole",
        );
        return 0;
    };
    let mut previous = 0i64;
    for (episode, &end) in ends.iter().enumerate() {
        if end <= previous {
            findings.error(At::file("meta/episode_ends").episode(episode as u64), Check::EpisodeEnds, format!("end {end} does not follow {previous} (episodes need at least one frame, ends increase)"));
        }
        previous = end;
    }
    if ends.last().copied().unwrap_or(0) as u64 != frames {
        findings.error(
            At::file("meta/episode_ends"),
            Check::EpisodeEnds,
            format!(
                "the last end is {}, the data arrays hold {frames} frames",
                ends.last().copied().unwrap_or(0)
            ),
        );
    }
    ends.len() as u64
}
