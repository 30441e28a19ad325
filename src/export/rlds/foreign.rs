//! Reading an RLDS dataset another tool wrote (an Open X-Embodiment dataset written by
//! tensorflow_datasets): [`ForeignRldsSource`], an [`EpisodeSource`] that takes its features
//! from the dataset's own `features.json`. The instruction, `action` and `observation.state`
//! are found by [`Mapping`] (fractal's `observation/natural_language_instruction` and action
//! dict, language_table's byte codes, ...); every other step-level tensor, text and image
//! becomes a [`FeatureKind::Other`] feature named the LeRobot way (`steps/observation/image` ->
//! `observation.images.image`, `steps/action/terminate_episode` -> `action.terminate_episode`);
//! `is_first` / `is_last` / `is_terminal` are structure, not features. What cannot be carried
//! (per-episode metadata, string tensors, images of unknown size) is named in the dataset
//! info's notes, which `convert` prints: nothing is left out silently. RLDS has no frame rate:
//! the caller gives one.

use crate::episode::{
    Dtype, Episode, EpisodeField, EpisodeMeta, FeatureKind, FeatureSpec, FeatureValue, FieldDtype,
    Step,
};
use crate::export::bounded::read_json;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::rlds::example::{Feature, decode_example};
use crate::export::rlds::generic::{Leaf, leaves};
use crate::export::rlds::mapping::{Instruction, Joined, Mapping};
use crate::export::rlds::options::SURGVLA_JSON;
use crate::export::rlds::read::{ShardRecords, invalid, version_dir};
use crate::export::source::EpisodeSource;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// Keys that are structure, not features.
const STRUCTURE: [&str; 3] = ["steps/is_first", "steps/is_last", "steps/is_terminal"];

/// The LeRobot name of an RLDS step key.
fn lerobot_name(key: &str, image: bool) -> String {
    let path = key.trim_start_matches("steps/");
    match path.strip_prefix("observation/") {
        Some(rest) if image => format!("observation.images.{}", rest.replace('/', ".")),
        _ => path.replace('/', "."),
    }
}

/// One feature read from the records: the RLDS keys it is made of (several for a joined
/// action or state, concatenated in order) with their element counts, and its spec.
#[derive(Clone, Debug)]
struct Column {
    parts: Vec<(String, usize)>,
    spec: FeatureSpec,
}

/// The dtype and shape a leaf is read as, or why it is left out.
fn read_as(key: &str, leaf: &Leaf) -> Result<(Dtype, Vec<usize>), String> {
    match leaf {
        Leaf::Image { shape, .. } => match shape {
            [Some(h), Some(w), Some(c)] => Ok((Dtype::Image, vec![*h, *w, *c])),
            _ => Err(format!(
                "left out {key}: an image of unknown size (surgvla needs fixed sizes)"
            )),
        },
        Leaf::Tensor {
            dtype, elements, ..
        } => match dtype.as_str() {
            "float32" | "float64" | "float16" => Ok((Dtype::Float32, vec![*elements])),
            "int64" | "int32" | "int16" | "int8" | "uint8" | "uint16" | "uint32" | "bool" => {
                Ok((Dtype::Int64, vec![*elements]))
            }
            other => Err(format!(
                "left out {key}: a {other} tensor, which surgvla does not read"
            )),
        },
        // One text per step: a string feature (e.g. instruction.text).
        Leaf::Text => Ok((Dtype::String, vec![1])),
    }
}

/// The name a carried key gets: its LeRobot name, with the dot after a joined feature's name
/// made an underscore (`steps/action/terminate_episode` beside a joined `action` is
/// `action_terminate_episode`), since a format of nested keys (RLDS) cannot hold `action` both
/// as a value and as a folder.
fn carried_name(key: &str, dtype: Dtype, mapping: &Mapping) -> String {
    let name = lerobot_name(key, dtype == Dtype::Image);
    for joined in &mapping.joined {
        if let Some(rest) = name.strip_prefix(&format!("{}.", joined.name)) {
            return format!("{}_{}", joined.name, rest.replace('.', "_"));
        }
    }
    name
}

/// The most values a per-episode field carried into LeRobot's episodes table may have.
const MAX_FIELD_VALUES: usize = 16;

/// Whether an episode-level leaf is carried as a per-episode field (a text, or a few numbers).
fn episode_field(leaf: &Leaf) -> bool {
    match leaf {
        Leaf::Text => true,
        Leaf::Tensor {
            dtype, elements, ..
        } => dtype != "string" && *elements <= MAX_FIELD_VALUES,
        Leaf::Image { .. } => false,
    }
}

/// The per-episode fields of a record: each carried episode-level leaf as JSON (a text, a
/// boolean, a number, or an array of them).
fn fields_of(
    leaves: &BTreeMap<String, Leaf>,
    example: &BTreeMap<String, Feature>,
) -> serde_json::Map<String, Value> {
    let mut fields = serde_json::Map::new();
    let carried = (leaves.iter()).filter(|(k, l)| !k.starts_with("steps/") && episode_field(l));
    for (key, leaf) in carried {
        let boolean = matches!(leaf, Leaf::Tensor { dtype, .. } if dtype == "bool");
        let mut values: Vec<Value> = match example.get(key) {
            Some(Feature::Bytes(texts)) => (texts.iter())
                .map(|t| Value::from(String::from_utf8_lossy(t).into_owned()))
                .collect(),
            Some(Feature::Int64(v)) if boolean => v.iter().map(|x| Value::from(*x != 0)).collect(),
            Some(Feature::Int64(v)) => v.iter().map(|x| Value::from(*x)).collect(),
            Some(Feature::Float(v)) => v.iter().map(|x| Value::from(f64::from(*x))).collect(),
            None => continue,
        };
        let value = match values.len() {
            1 => values.remove(0),
            _ => Value::Array(values),
        };
        fields.insert(key.clone(), value);
    }
    fields
}

/// The feature info key of a flattened tensor's declared shape (e.g. `[150, 200]`).
pub const SHAPE_KEY: &str = "rlds_shape";

/// The per-episode leaves carried, declared as [`EpisodeField`]s (in key order).
fn declared(leaves: &BTreeMap<String, Leaf>) -> Vec<EpisodeField> {
    (leaves.iter())
        .filter_map(|(key, leaf)| {
            let (dtype, len) = match leaf {
                Leaf::Text => (FieldDtype::Text, 1),
                Leaf::Tensor {
                    dtype, elements, ..
                } => {
                    let kind = match dtype.as_str() {
                        "bool" => FieldDtype::Bool,
                        d if d.starts_with("float") => FieldDtype::Float,
                        _ => FieldDtype::Int64,
                    };
                    (kind, (*elements).max(1))
                }
                Leaf::Image { .. } => return None,
            };
            Some(EpisodeField {
                key: key.clone(),
                dtype,
                len,
            })
        })
        .collect()
}

/// A feature spec surgvla has no role for.
fn other(name: String, dtype: Dtype, shape: Vec<usize>, names: Vec<String>) -> FeatureSpec {
    FeatureSpec {
        name,
        dtype,
        shape,
        names,
        kind: FeatureKind::Other,
        video: None,
        info: Default::default(),
    }
}

/// Element names of a joined feature: each part's last key segment, indexed when it has
/// several values.
fn part_names(parts: &[(String, usize)]) -> Vec<String> {
    let mut names = Vec::new();
    for (key, n) in parts {
        let part = key.rsplit('/').next().unwrap_or(key);
        if *n == 1 {
            names.push(part.to_string());
        } else {
            names.extend((0..*n).map(|i| format!("{part}_{i}")));
        }
    }
    names
}

/// The columns of a dataset with these leaves read through `mapping`, and the notes a
/// conversion prints: how the mapping read the dataset, what it left out. `Err` names a
/// key whose feature name a map's feature took.
fn columns(
    leaves: &BTreeMap<String, Leaf>,
    mapping: &Mapping,
) -> Result<(Vec<Column>, Vec<String>), String> {
    let mut notes = mapping.describe();
    let mut columns = Vec::new();
    for joined in &mapping.joined {
        let parts: Vec<(String, usize)> = (joined.keys.iter())
            .filter_map(|key| match leaves.get(key)? {
                Leaf::Tensor { elements, .. } => Some((key.clone(), *elements)),
                _ => None,
            })
            .collect();
        let total = parts.iter().map(|(_, n)| n).sum();
        let names = match joined.names.len() == total {
            true => joined.names.clone(),
            false => part_names(&parts),
        };
        columns.push(Column {
            spec: other(joined.name.clone(), Dtype::Float32, vec![total], names),
            parts,
        });
    }
    for (key, leaf) in leaves {
        if !key.starts_with("steps/") {
            notes.push(match episode_field(leaf) {
                true => format!(
                    "{key}: per episode, carried as the LeRobot episodes table's column {key} (RLDS: the same key; MCAP, PLY, PCD: episodes.jsonl's fields)"
                ),
                false => format!("left out {key}: per-episode values surgvla does not carry"),
            });
            continue;
        }
        if STRUCTURE.contains(&key.as_str()) || mapping.takes(key) {
            continue;
        }
        match read_as(key, leaf) {
            Ok((dtype, shape)) => {
                let name = carried_name(key, dtype, mapping);
                if columns.iter().any(|c: &Column| c.spec.name == name) {
                    return Err(format!(
                        "{key} would be the feature {name}, which the map's feature of that name already is: add the key to it, or name the map's feature otherwise"
                    ));
                }
                let mut spec = other(name, dtype, shape, Vec::new());
                // A 16-bit image in an RLDS dataset is a depth map (OXE's depth keys): it says
                // so to LeRobot, its PNG bytes unchanged.
                if matches!(leaf, Leaf::Image { dtype, .. } if dtype == "uint16") {
                    spec.info.insert("is_depth_map".into(), Value::Bool(true));
                }
                // A tensor of several dimensions travels flattened; its shape goes with it
                // (LeRobot: the feature's info), for an RLDS output to declare again.
                if let Leaf::Tensor { dims, .. } = leaf
                    && dims.len() > 1
                {
                    spec.info
                        .insert(SHAPE_KEY.into(), Value::from(dims.clone()));
                }
                columns.push(Column {
                    parts: vec![(key.clone(), spec.shape.iter().product())],
                    spec,
                });
            }
            Err(note) => notes.push(note),
        }
        if matches!(leaf, Leaf::Tensor { dtype, .. } if dtype == "float64") {
            notes.push(format!(
                "{key} is declared float64, but TFRecord files store float32: read as float32, no value changes"
            ));
        }
    }
    Ok((columns, notes))
}

/// The longest text of `dataset_info.json` repeated in a note.
const MAX_DESCRIBED_CHARS: usize = 2000;

/// What the dataset says of itself in `dataset_info.json` (name, version, licence, homepage,
/// citation), as notes: the card of a conversion says where the data came from. A file that
/// cannot be read says nothing here (reading the records names it).
fn described(folder: &Path) -> Vec<String> {
    let Ok(info) = read_json(&folder.join("dataset_info.json")) else {
        return Vec::new();
    };
    // One line each, and no longer than a citation needs: the file is another tool's.
    let text = |value: &Value| {
        (value.as_str())
            .map(|s| s.split_whitespace().collect::<Vec<_>>().join(" "))
            .filter(|s| !s.is_empty())
            .map(|s| match s.char_indices().nth(MAX_DESCRIBED_CHARS) {
                Some((cut, _)) => format!("{}...", &s[..cut]),
                None => s,
            })
    };
    let name = text(&info["name"]).unwrap_or_else(|| "unnamed".into());
    let version = text(&info["version"]).unwrap_or_else(|| "of no version".into());
    let mut line = format!("the input is the RLDS dataset {name} {version}");
    match text(&info["redistributionInfo"]["license"]) {
        Some(licence) => line.push_str(&format!(", licence: {licence}")),
        None => line.push_str(", which states no licence"),
    }
    if let Some(homepage) = text(&info["homepage"]) {
        line.push_str(&format!(", homepage {homepage}"));
    }
    let mut notes = vec![line];
    if let Some(citation) = text(&info["citation"]) {
        notes.push(format!("its authors ask to be cited as: {citation}"));
    }
    notes
}

/// Reads an RLDS dataset another tool wrote, episode by episode (one record in memory).
pub struct ForeignRldsSource {
    info: DatasetInfo,
    reading: Reading,
    records: ShardRecords,
    next_index: u64,
}

/// How a record becomes an episode: its columns, where its instruction is, the
/// episode-level leaves carried as per-episode fields.
struct Reading {
    columns: Vec<Column>,
    instruction: Option<Instruction>,
    episode_leaves: BTreeMap<String, Leaf>,
}

impl ForeignRldsSource {
    /// Opens the dataset at `path` (a version folder or the data directory above it) with
    /// `fps` steps per second and robot type `robot_type`.
    /// `map` (`convert --map`) names features the rules would not find.
    pub fn open(
        path: &Path,
        fps: u32,
        robot_type: &str,
        map: &[Joined],
    ) -> Result<Self, ExportError> {
        let folder = version_dir(path)?;
        let records = ShardRecords::open(&folder)?;
        let features_path = folder.join("features.json");
        let leaves = leaves(&read_json(&features_path)?)
            .map_err(|problem| invalid(&features_path, problem))?;
        let mapping = (Mapping::of(&leaves).with(map, &leaves)).map_err(|problem| {
            ExportError::InvalidOptions(format!("--map for {}: {problem}", folder.display()))
        })?;
        let (columns, notes) = columns(&leaves, &mapping).map_err(|problem| {
            ExportError::InvalidOptions(format!("--map for {}: {problem}", folder.display()))
        })?;
        let features: Vec<FeatureSpec> = columns.iter().map(|c| c.spec.clone()).collect();
        let mut info = DatasetInfo::from_surgvla_json(&Value::Null, fps, robot_type, features);
        info.notes = described(&folder);
        info.notes.extend(notes);
        info.splits = records.named_split();
        let episode_leaves: BTreeMap<String, Leaf> = (leaves.into_iter())
            .filter(|(k, l)| !k.starts_with("steps/") && episode_field(l))
            .collect();
        info.episode_fields = declared(&episode_leaves);
        Ok(ForeignRldsSource {
            info,
            reading: Reading {
                columns,
                instruction: mapping.instruction,
                episode_leaves,
            },
            records,
            next_index: 0,
        })
    }

    /// Each step's instruction: texts, or UTF-8 byte codes padded with zeros.
    fn instructions(
        instruction: Option<&Instruction>,
        example: &BTreeMap<String, Feature>,
        steps: usize,
    ) -> Result<Vec<String>, String> {
        let Some(instruction) = instruction else {
            return Ok(Vec::new());
        };
        let wrong = || format!("{} does not hold {steps} instructions", instruction.key);
        let texts: Vec<String> = match example.get(&instruction.key) {
            Some(Feature::Bytes(texts)) if !instruction.codes => (texts.iter())
                .map(|t| String::from_utf8_lossy(t).into_owned())
                .collect(),
            Some(Feature::Int64(codes)) if instruction.codes && codes.len() % steps.max(1) == 0 => {
                let per_step = codes.len() / steps.max(1);
                (codes.chunks(per_step.max(1)))
                    .map(|step| {
                        let bytes: Vec<u8> = (step.iter())
                            .take_while(|c| **c != 0)
                            .map(|c| u8::try_from(*c).unwrap_or(b'?'))
                            .collect();
                        String::from_utf8_lossy(&bytes).into_owned()
                    })
                    .collect()
            }
            _ => return Err(wrong()),
        };
        if texts.len() != steps {
            return Err(wrong());
        }
        Ok(texts)
    }

    /// Step `i`'s value of `column`.
    fn value(
        column: &Column,
        example: &BTreeMap<String, Feature>,
        i: usize,
        steps: usize,
    ) -> Result<FeatureValue, String> {
        let wrong = |key: &str| {
            format!(
                "{key} does not hold {steps} steps of {:?}",
                column.spec.shape
            )
        };
        // Only a float column gathers values here (an image's are its bytes, not pixels).
        let mut floats = match column.spec.dtype {
            Dtype::Float32 => Vec::with_capacity(column.spec.shape.iter().product()),
            _ => Vec::new(),
        };
        for (key, n) in &column.parts {
            let n = *n;
            let values = example.get(key).ok_or_else(|| wrong(key))?;
            let value = match (column.spec.dtype, values) {
                (Dtype::Image, Feature::Bytes(images)) => {
                    FeatureValue::Image(images.get(i).ok_or_else(|| wrong(key))?.clone())
                }
                (Dtype::Float32, Feature::Float(v)) => {
                    floats.extend_from_slice(v.get(i * n..(i + 1) * n).ok_or_else(|| wrong(key))?);
                    continue;
                }
                // A flag or count joining a float vector (bridge's open_gripper): exact.
                (Dtype::Float32, Feature::Int64(v)) => {
                    let part = v.get(i * n..(i + 1) * n).ok_or_else(|| wrong(key))?;
                    floats.extend(part.iter().map(|x| *x as f32));
                    continue;
                }
                (Dtype::Int64, Feature::Int64(v)) => FeatureValue::Int64(
                    v.get(i * n..(i + 1) * n)
                        .ok_or_else(|| wrong(key))?
                        .to_vec(),
                ),
                (Dtype::String, Feature::Bytes(texts)) => FeatureValue::Text(
                    String::from_utf8_lossy(texts.get(i).ok_or_else(|| wrong(key))?).into_owned(),
                ),
                _ => return Err(wrong(key)),
            };
            return Ok(value);
        }
        Ok(FeatureValue::Float32(floats))
    }
}

impl Reading {
    /// Episode `index` from its record.
    fn decode(&self, bytes: &[u8], index: u64) -> Result<Episode, String> {
        let (columns, instruction) = (&self.columns, self.instruction.as_ref());
        let example = decode_example(bytes).map_err(|e| e.0.to_string())?;
        let steps = match example.get("steps/is_first") {
            Some(Feature::Int64(flags)) => flags.len(),
            _ => return Err("steps/is_first is missing".into()),
        };
        if steps == 0 {
            return Err("the episode has zero steps".into());
        }
        let texts = ForeignRldsSource::instructions(instruction, &example, steps)?;
        let task_changes = EpisodeMeta::changes_of(texts.iter().map(String::as_str));
        let instruction = texts.into_iter().next().unwrap_or_default();
        let mut rows: Vec<Vec<FeatureValue>> = vec![Vec::with_capacity(columns.len()); steps];
        for column in columns {
            for (i, row) in rows.iter_mut().enumerate() {
                row.push(ForeignRldsSource::value(column, &example, i, steps)?);
            }
        }
        Ok(Episode {
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
            meta: EpisodeMeta {
                task_changes,
                fields: fields_of(&self.episode_leaves, &example),
                ..EpisodeMeta::foreign(index, instruction)
            },
            steps: rows
                .into_iter()
                .map(|other| Step {
                    other,
                    ..Step::empty()
                })
                .collect(),
        })
    }
}
impl Iterator for ForeignRldsSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let index = self.next_index;
        self.next_index += 1;
        let reading = &self.reading;
        (self.records).next_decoded(|bytes| reading.decode(bytes, index))
    }
}

impl EpisodeSource for ForeignRldsSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.records.total()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next_index += 1;
        self.records.next_decoded(|_| Ok(()))
    }
}

/// Reads an RLDS version folder: ours (with `surgvla.json`), or another tool's through its own
/// `features.json`, which needs `options.fps`.
pub fn open_any(
    folder: &std::path::Path,
    options: &crate::export::source::SourceOptions,
) -> Result<Box<dyn crate::export::source::EpisodeSource + Send>, ExportError> {
    if folder.join(SURGVLA_JSON).is_file() {
        if !options.map.is_empty() {
            return Err(ExportError::InvalidOptions(format!(
                "--map is for RLDS datasets another tool wrote; {} is surgvla's, whose features are named already",
                folder.display()
            )));
        }
        return Ok(Box::new(super::read::RldsSource::open(folder)?));
    }
    let fps = options.fps.ok_or_else(|| ExportError::NoFrameRate {
        path: folder.to_path_buf(),
    })?;
    let robot_type = options.robot_type.as_deref().unwrap_or("unknown");
    Ok(Box::new(super::foreign::ForeignRldsSource::open(
        folder,
        fps,
        robot_type,
        &options.map,
    )?))
}
