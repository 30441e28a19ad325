//! Reading an RLDS dataset back: [`RldsSource`], an [`EpisodeSource`] of the TFDS layout this
//! module writes (and of other RLDS datasets with the same step keys). It checks what the real
//! readers check (record CRCs, shard names, `shardLengths`, per-key step counts, image shapes)
//! and names the shard and record of a defect. Interop is proven with `tensorflow_datasets` in
//! `tests/interop/`.

use crate::episode::{Episode, FeatureSet, standard_features};
use crate::export::bounded::read_json;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::rlds::options::{RldsKeys, SURGVLA_JSON};
use crate::export::rlds::record::{StepLayout, decode_episode};
use crate::export::rlds::tfrecord::{RecordError, RecordReader};
use crate::export::source::EpisodeSource;
use serde_json::Value;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

pub(super) fn invalid(path: &Path, problem: impl Into<String>) -> ExportError {
    ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Whether `path` holds an RLDS dataset: a version folder with `dataset_info.json`, or a data
/// directory with `<name>/<version>/dataset_info.json` in it.
pub fn is_rlds(path: &Path) -> bool {
    version_dir(path).is_ok()
}

/// x.y.z as numbers, for ordering versions.
fn version_number(name: &str) -> Option<[u64; 3]> {
    let parts: Vec<u64> = name
        .split('.')
        .map(str::parse)
        .collect::<Result<_, _>>()
        .ok()?;
    parts.try_into().ok()
}

/// The version folder `path` names: itself, the highest version of a dataset folder
/// (`<name>/`), or in a data directory the highest version of its one dataset.
pub fn version_dir(path: &Path) -> Result<PathBuf, ExportError> {
    if path.join("dataset_info.json").is_file() {
        return Ok(path.to_path_buf());
    }
    // A dataset's own folder: its versions.
    if let Some(folder) = highest_version(path) {
        return Ok(folder);
    }
    let found = datasets_below(path);
    match found.len() {
        0 => Err(invalid(
            path,
            "no dataset_info.json here or in <name>/<version>/ below: not an RLDS dataset, or an incomplete one",
        )),
        1 => Ok(found
            .into_iter()
            .map(|(_, folder)| folder)
            .next()
            .unwrap_or_default()),
        _ => Err(invalid(
            path,
            format!(
                "holds several RLDS datasets ({}): give one of them as {}/<name>",
                found
                    .iter()
                    .map(|(name, _)| name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                path.display()
            ),
        )),
    }
}

/// The highest version folder (`x.y.z` holding `dataset_info.json`) directly in `folder`.
fn highest_version(folder: &Path) -> Option<PathBuf> {
    let versions = std::fs::read_dir(folder).ok()?;
    versions
        .flatten()
        .filter_map(|version| {
            let number = version_number(&version.file_name().to_string_lossy())?;
            let path = version.path();
            path.join("dataset_info.json")
                .is_file()
                .then_some((number, path))
        })
        .max_by_key(|(number, _)| *number)
        .map(|(_, path)| path)
}

/// The datasets of a TFDS data directory, by name (sorted): each one's highest version folder.
pub fn datasets_below(path: &Path) -> Vec<(String, PathBuf)> {
    let Ok(entries) = std::fs::read_dir(path) else {
        return Vec::new();
    };
    let mut found: Vec<(String, PathBuf)> = entries
        .flatten()
        .filter_map(|entry| {
            let name = entry.file_name().to_string_lossy().into_owned();
            Some((name, highest_version(&entry.path())?))
        })
        .collect();
    found.sort();
    found
}

/// The observation node of features.json.
fn observation_features(features: &Value) -> Option<&serde_json::Map<String, Value>> {
    features["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"]["features"]
        ["observation"]["featuresDict"]["features"]
        .as_object()
}

/// (height, width) of an image node.
fn image_size(node: &Value) -> Option<(usize, usize)> {
    let dimensions = node["image"]["shape"]["dimensions"].as_array()?;
    let dimension = |i: usize| -> Option<usize> {
        let value = dimensions.get(i)?;
        value
            .as_str()
            .and_then(|s| s.parse().ok())
            .or_else(|| value.as_u64().map(|v| v as usize))
    };
    Some((dimension(0)?, dimension(1)?))
}

/// A shard of the train split: its path and the episodes dataset_info.json says it holds.
struct Shard {
    path: PathBuf,
    episodes: u64,
}

/// The episode records of a TFDS train split, shard by shard in order, one record in memory at
/// a time; each shard must hold the episodes `dataset_info.json`'s `shardLengths` gives it. After
/// the first error (its own, or a record its caller could not decode) it yields nothing more.
/// Both RLDS sources read through it: ours and [`super::foreign::ForeignRldsSource`].
pub struct ShardRecords {
    shards: std::vec::IntoIter<Shard>,
    /// The shard being read: path, reader, episodes expected and read.
    current: Option<(PathBuf, RecordReader<BufReader<File>>, u64, u64)>,
    total: u64,
    /// The split read ([`super::options::read_split`]).
    split: String,
    failed: bool,
}

impl ShardRecords {
    /// The shards of the version folder `folder`'s split (`train`, else its only one), as
    /// `dataset_info.json` lists them (every one present).
    pub fn open(folder: &Path) -> Result<ShardRecords, ExportError> {
        let info_path = folder.join("dataset_info.json");
        let dataset_info = read_json(&info_path)?;
        let name = dataset_info["name"]
            .as_str()
            .ok_or_else(|| invalid(&info_path, "has no name"))?;
        crate::export::paths::component(name).map_err(|problem| ExportError::UnsafeName {
            path: info_path.clone(),
            what: "dataset name",
            name: name.to_string(),
            problem,
        })?;
        let (split_name, split) = super::options::read_split(&dataset_info).ok_or_else(|| {
            invalid(
                &info_path,
                "has no train split, nor one split alone named with letters, digits, _ or -",
            )
        })?;
        let lengths: Vec<u64> = split["shardLengths"]
            .as_array()
            .ok_or_else(|| {
                invalid(
                    &info_path,
                    format!("the {split_name} split has no shardLengths"),
                )
            })?
            .iter()
            .map(|v| {
                v.as_str()
                    .and_then(|s| s.parse().ok())
                    .or_else(|| v.as_u64())
                    .ok_or_else(|| invalid(&info_path, format!("shard length {v} is not a count")))
            })
            .collect::<Result<_, _>>()?;
        let count = lengths.len();
        if count > 100_000 {
            return Err(invalid(
                &info_path,
                format!("lists {count} shards (TFDS numbers at most 100000)"),
            ));
        }
        let shards: Vec<Shard> = lengths
            .iter()
            .enumerate()
            .map(|(i, &episodes)| {
                let path =
                    folder.join(format!("{name}-{split_name}.tfrecord-{i:05}-of-{count:05}"));
                if path.is_file() {
                    Ok(Shard { path, episodes })
                } else {
                    Err(invalid(
                        &path,
                        format!("is missing (dataset_info.json lists {count} shards)"),
                    ))
                }
            })
            .collect::<Result<_, _>>()?;
        Ok(ShardRecords {
            shards: shards.into_iter(),
            current: None,
            total: lengths.iter().sum(),
            split: split_name.to_string(),
            failed: false,
        })
    }

    /// Episodes the split holds, by `shardLengths`.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// The split's name as `info.splits` carries it: none for `train` (every dataset's
    /// default), else the split covering every episode (a split `edit` wrote on its own).
    pub fn named_split(&self) -> Vec<(String, std::ops::Range<u64>)> {
        match self.split.as_str() {
            "train" => Vec::new(),
            name => vec![(name.to_string(), 0..self.total)],
        }
    }

    /// The next record decoded by `decode` (a failure names the shard and the record), or None
    /// after the last record or the first error.
    pub fn next_decoded<T>(
        &mut self,
        decode: impl FnOnce(&[u8]) -> Result<T, String>,
    ) -> Option<Result<T, ExportError>> {
        if self.failed {
            return None;
        }
        let result = match self.next_record() {
            Ok(None) => return None,
            Ok(Some((path, index, bytes))) => decode(&bytes)
                .map_err(|problem| invalid(&path, format!("record {index}: {problem}"))),
            Err(error) => Err(error),
        };
        self.failed = result.is_err();
        Some(result)
    }

    /// The next record: (its shard, its index in the shard, its bytes).
    fn next_record(&mut self) -> Result<Option<(PathBuf, u64, Vec<u8>)>, ExportError> {
        loop {
            if self.current.is_none() {
                let Some(shard) = self.shards.next() else {
                    return Ok(None);
                };
                let file = crate::export::bounded::open_regular(&shard.path)?;
                let reader = RecordReader::new(BufReader::with_capacity(1 << 20, file));
                self.current = Some((shard.path, reader, shard.episodes, 0));
            }
            let Some((path, reader, expected, read)) = self.current.as_mut() else {
                continue;
            };
            match reader.next_record() {
                Some(Ok(bytes)) => {
                    let index = *read;
                    *read += 1;
                    if *read > *expected {
                        return Err(invalid(
                            path,
                            format!(
                                "holds more than the {expected} episodes dataset_info.json's shardLengths gives it"
                            ),
                        ));
                    }
                    return Ok(Some((path.clone(), index, bytes)));
                }
                Some(Err(RecordError::Io { source, .. })) => {
                    return Err(ExportError::Io {
                        path: path.clone(),
                        source,
                    });
                }
                Some(Err(error)) => return Err(invalid(path, error.to_string())),
                None => {
                    if *read != *expected {
                        return Err(invalid(
                            path,
                            format!(
                                "holds {read} episodes where dataset_info.json's shardLengths gives {expected}"
                            ),
                        ));
                    }
                    self.current = None;
                }
            }
        }
    }
}

/// Reads an RLDS dataset surgvla wrote, episode by episode (one record in memory at a time).
pub struct RldsSource {
    info: DatasetInfo,
    layout: StepLayout,
    records: ShardRecords,
}

impl RldsSource {
    /// Opens the dataset at `path` (a version folder or the data directory above it).
    pub fn open(path: &Path) -> Result<Self, ExportError> {
        let folder = version_dir(path)?;
        let records = ShardRecords::open(&folder)?;
        let features_path = folder.join("features.json");
        if !features_path.is_file() {
            return Err(invalid(&features_path, "is missing"));
        }
        let features = read_json(&features_path)?;
        let surgvla_path = folder.join(SURGVLA_JSON);
        let surgvla = if surgvla_path.is_file() {
            read_json(&surgvla_path)?
        } else {
            Value::Null
        };
        let keys: RldsKeys =
            serde_json::from_value(surgvla["rlds"]["keys"].clone()).unwrap_or_default();
        let observation = observation_features(&features)
            .ok_or_else(|| invalid(&features_path, "has no steps/observation features"))?;
        let (height, width) = observation
            .get(&keys.image)
            .and_then(image_size)
            .ok_or_else(|| {
                invalid(
                    &features_path,
                    format!("has no image feature steps/observation/{}", keys.image),
                )
            })?;
        if !observation.contains_key(&keys.state) {
            return Err(invalid(
                &features_path,
                format!("has no steps/observation/{}", keys.state),
            ));
        }
        let set = FeatureSet {
            depth: observation.contains_key(&keys.depth),
            mask: observation.contains_key(&keys.mask),
            environment_state: observation.contains_key(&keys.environment_state),
        };
        let mut info = DatasetInfo::from_surgvla_json(
            &surgvla,
            surgvla["fps"].as_u64().unwrap_or(0) as u32,
            surgvla["robot_type"].as_str().unwrap_or_default(),
            standard_features(height, width, set),
        );
        info.splits = records.named_split();
        Ok(RldsSource {
            layout: StepLayout::of(&info, &keys),
            info,
            records,
        })
    }
}
impl Iterator for RldsSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let layout = &self.layout;
        self.records
            .next_decoded(|bytes| decode_episode(layout, bytes))
    }
}

impl EpisodeSource for RldsSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.records.total()
    }

    /// The record is read (its framing and CRC checked) but not decoded.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.records.next_decoded(|_| Ok(()))
    }
}
