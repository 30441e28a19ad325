//! What an RLDS dataset is written with: [`RldsOptions`] (name, version, shard size, keys, image
//! encoding) and the names of its metadata files.

use crate::export::dir::RunOptions;
use crate::export::error::ExportError;
use crate::export::paths;
use crate::media::image::PngLevel;
use serde::{Deserialize, Serialize};

/// Every file with its size and CRC-32C, at the top of the output folder.
pub const MANIFEST: &str = "surgvla_manifest.json";

/// The guide beside the dataset.
pub const OPENVLA_GUIDE: &str = "OPENVLA.md";

/// surgvla's own metadata inside the version folder.
pub const SURGVLA_JSON: &str = "surgvla.json";

/// Where another tool's feature goes in an RLDS step: `observation.images.X` ->
/// `observation/X`, otherwise its dotted name as a path (`observation.state` ->
/// `observation/state`, `action` -> `action`); [`crate::export::rlds::foreign`] reads the names back.
pub fn rlds_path(name: &str) -> Vec<String> {
    match name.strip_prefix("observation.images.") {
        Some(camera) => vec!["observation".into(), camera.replace('.', "_")],
        None => name.split('.').map(String::from).collect(),
    }
}

/// The observation keys of a step (`steps/observation/<key>`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RldsKeys {
    /// The RGB camera (OpenVLA's primary image key).
    pub image: String,
    pub depth: String,
    pub mask: String,
    pub state: String,
    pub environment_state: String,
}

impl Default for RldsKeys {
    /// OpenVLA-friendly names: `image`, `depth`, `mask`, `state`, `environment_state`.
    fn default() -> Self {
        RldsKeys {
            image: "image".into(),
            depth: "depth".into(),
            mask: "mask".into(),
            state: "state".into(),
            environment_state: "environment_state".into(),
        }
    }
}

/// Options of the RLDS format.
#[derive(Clone, Debug, PartialEq)]
pub struct RldsOptions {
    /// The dataset name (folder and shard prefix; what `tfds.builder(name)` takes).
    pub name: String,
    /// The version folder, x.y.z.
    pub version: String,
    /// A shard is closed once it reaches this size.
    pub shard_size_mb: u64,
    pub png: PngLevel,
    pub keys: RldsKeys,
    /// The RGB camera as JPEG of this quality (1-100) instead of PNG: what Open X-Embodiment
    /// and OpenVLA's datasets store, a fraction of the size, lossy.
    pub jpeg_quality: Option<u8>,
}

/// The options an RLDS dataset records (see [`RldsOptions::run_options`]), read back by its
/// merge.
#[derive(Serialize, Deserialize)]
struct Recorded {
    format: String,
    rlds_name: String,
    rlds_version: String,
    rlds_shard_mb: u64,
    png: PngLevel,
    rlds_keys: RldsKeys,
    /// Only when the RGB camera is JPEG.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    rlds_jpeg_quality: Option<u8>,
}

impl Default for RldsOptions {
    fn default() -> Self {
        RldsOptions {
            name: "surgvla_benchmark".into(),
            version: "1.0.0".into(),
            shard_size_mb: 64,
            png: PngLevel::Fast,
            keys: RldsKeys::default(),
            jpeg_quality: None,
        }
    }
}

impl RldsOptions {
    /// Refuses a name TFDS cannot load, a version that is not x.y.z, or keys that are empty,
    /// contain '/' or repeat.
    pub fn check(&self) -> Result<(), ExportError> {
        let bad = |problem: String| Err(ExportError::InvalidOptions(problem));
        let name = &self.name;
        let snake = name.starts_with(|c: char| c.is_ascii_lowercase())
            && name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !snake {
            return bad(format!(
                "RLDS name {name:?} must be snake_case (a-z, 0-9, _; starting with a letter), as tfds.builder requires"
            ));
        }
        let parts: Vec<&str> = self.version.split('.').collect();
        if parts.len() != 3
            || parts
                .iter()
                .any(|p| p.is_empty() || !p.chars().all(|c| c.is_ascii_digit()))
        {
            return bad(format!(
                "RLDS version {:?} must be x.y.z, e.g. 1.0.0",
                self.version
            ));
        }
        let keys = &self.keys;
        let all = [
            &keys.image,
            &keys.depth,
            &keys.mask,
            &keys.state,
            &keys.environment_state,
        ];
        for (i, key) in all.iter().enumerate() {
            if !crate::export::paths::is_plain_name(key) {
                return bad(format!(
                    "RLDS observation key {key:?} must be 1 to 64 letters, digits, _ or -"
                ));
            }
            if all[..i].contains(key) {
                return bad(format!("RLDS observation key {key:?} is given twice"));
            }
        }
        Ok(())
    }

    /// What these options change in the bytes, by option name (for resume).
    pub fn run_options(&self) -> RunOptions {
        RunOptions::recorded(&Recorded {
            format: "rlds".into(),
            rlds_name: self.name.clone(),
            rlds_version: self.version.clone(),
            rlds_shard_mb: self.shard_size_mb,
            png: self.png,
            rlds_keys: self.keys.clone(),
            rlds_jpeg_quality: self.jpeg_quality,
        })
    }

    /// The options a dataset recorded ([`RldsOptions::run_options`], in its manifest); None
    /// when an option is missing or not of its type.
    pub fn from_run_options(run: &RunOptions) -> Option<RldsOptions> {
        let recorded: Recorded = run.read()?;
        Some(RldsOptions {
            name: recorded.rlds_name,
            version: recorded.rlds_version,
            shard_size_mb: recorded.rlds_shard_mb,
            png: recorded.png,
            keys: recorded.rlds_keys,
            jpeg_quality: recorded.rlds_jpeg_quality,
        })
    }

    /// The version folder, relative to the output folder.
    pub fn version_dir(&self) -> String {
        format!("{}/{}", self.name, self.version)
    }

    /// Shard `index` of `count` of `split` (`count` None: the name while the run is going on).
    pub fn shard_path(&self, split: &str, index: usize, count: Option<usize>) -> String {
        let base = format!(
            "{}/{}-{split}.tfrecord-{index:05}",
            self.version_dir(),
            self.name
        );
        match count {
            Some(count) => format!("{base}-of-{count:05}"),
            None => base,
        }
    }
}

/// The TFDS split a dataset's episodes are written in: the one split its metadata names when it
/// names one (`edit --split` writes a dataset per split), else `train` (several splits in one
/// dataset are written as one: RLDS here holds one split a dataset).
pub(super) fn tfds_split(splits: &[(String, std::ops::Range<u64>)]) -> &str {
    match splits {
        [(name, _)] if paths::is_plain_name(name) => name,
        _ => "train",
    }
}

/// The split an RLDS dataset's episodes are read from, with its name: `train` when
/// `dataset_info.json` lists it, else its only split (a split `edit` wrote on its own); None
/// when it lists neither, or the split's name is not plain ([`paths::is_plain_name`]: it
/// becomes part of a shard's file name).
pub(super) fn read_split(dataset_info: &serde_json::Value) -> Option<(&str, &serde_json::Value)> {
    let splits = dataset_info["splits"].as_array()?;
    let only = match splits.as_slice() {
        [only] => Some(only),
        _ => None,
    };
    let split = (splits.iter().find(|s| s["name"] == "train")).or(only)?;
    let name = split["name"].as_str().filter(|n| paths::is_plain_name(n))?;
    Some((name, split))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{Value, json};

    #[test]
    fn a_dataset_is_written_and_read_in_one_split_whose_name_is_safe_in_a_file_name() {
        let mut named: Vec<(String, std::ops::Range<u64>)> = Vec::new();
        assert_eq!(tfds_split(&named), "train");
        named = vec![("val-2".into(), 0..4)];
        assert_eq!(tfds_split(&named), "val-2");
        named.push(("test".into(), 4..6));
        assert_eq!(
            tfds_split(&named),
            "train",
            "several splits are written as one"
        );
        named = vec![("../x".into(), 0..4)];
        assert_eq!(tfds_split(&named), "train");
        let read = |splits: Value| {
            read_split(&json!({ "splits": splits })).map(|(name, _)| name.to_string())
        };
        assert_eq!(
            read(json!([{"name": "test"}, {"name": "train"}])),
            Some("train".to_string())
        );
        assert_eq!(read(json!([{"name": "val"}])), Some("val".to_string()));
        assert_eq!(read(json!([{"name": "val"}, {"name": "test"}])), None);
        for unsafe_name in ["../../x", "a/b", "", "val.tfrecord"] {
            assert_eq!(
                read(json!([{ "name": unsafe_name }])),
                None,
                "{unsafe_name}"
            );
        }
    }
}
