//! MCAP folders' merge: a recording carries its episode's number (the `episode` Metadata
//! record and the `/episode/info` message) and its own index and CRCs, so each file is
//! re-packed: its records read in order and written again through the writer every episode
//! file is written with ([`super::writer::new_writer`]), the same schemas, channels and messages with
//! the new number, so the chunks, indexes and summary come out as one run writes them.
//! `episodes.jsonl` gets each line again with the new `episode_index` and `file`
//! ([`crate::export::merge::merge_episode_files`]). N of N merged are the single run's bytes.
//! `--resume` starts an interrupted MCAP merge over in its folder
//! ([`crate::export::merge::output_dir`]).

use super::writer::{MANIFEST, mcap_error};
use crate::export::bounded::read_capped;
use crate::export::bounded::read_json;
use crate::export::collection::{Collection, SHARD_KEY};
use crate::export::convert::ConvertError;
use crate::export::dir::{DatasetDir, RunOptions};
use crate::export::error::ExportError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::merge::{Part, merge_episode_files, plan};
use crate::export::sink::Summary;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::path::Path;

/// One line per episode.
const EPISODES: &str = "episodes.jsonl";
/// The topic whose JSON message states the episode's number.
const INFO_TOPIC: &str = "/episode/info";
/// The Metadata record with the episode's provenance.
const EPISODE_METADATA: &str = "episode";
/// An episode's recording larger than this is not one surgvla writes.
const MAX_FILE_BYTES: u64 = 4 << 30;

fn file_of(index: u64) -> String {
    format!("episode_{index:06}.mcap")
}

/// What a recording holds up to its data's end, in the order it was written.
#[derive(Default)]
struct Recording {
    library: String,
    metadata: Vec<mcap::records::Metadata>,
    /// (id, name, encoding, data), in id order.
    schemas: BTreeMap<u16, (String, String, Vec<u8>)>,
    channels: BTreeMap<u16, mcap::records::Channel>,
    messages: Vec<(mcap::records::MessageHeader, Vec<u8>)>,
}

fn read_recording(path: &Path) -> Result<Recording, ExportError> {
    let bytes = read_capped(path, MAX_FILE_BYTES)?;
    let invalid = |e: mcap::McapError| ExportError::InvalidDataset {
        path: path.to_path_buf(),
        problem: format!("is not a readable MCAP recording: {e}"),
    };
    // The mcap reader reserves each chunk's claimed uncompressed size before decompressing it.
    if let Some(problem) = super::check::chunks_problem(&bytes) {
        return Err(ExportError::InvalidDataset {
            path: path.to_path_buf(),
            problem,
        });
    }
    let mut recording = Recording::default();
    let options = mcap::read::Options::ValidateChunkCrcs.into();
    for record in mcap::read::ChunkFlattener::new_with_options(&bytes, options).map_err(invalid)? {
        match record.map_err(invalid)? {
            mcap::records::Record::Header(header) => recording.library = header.library,
            mcap::records::Record::Metadata(metadata) => recording.metadata.push(metadata),
            mcap::records::Record::Schema { header, data } => {
                recording
                    .schemas
                    .insert(header.id, (header.name, header.encoding, data.into_owned()));
            }
            mcap::records::Record::Channel(channel) => {
                recording.channels.insert(channel.id, channel);
            }
            mcap::records::Record::Message { header, data } => {
                recording.messages.push((header, data.into_owned()))
            }
            mcap::records::Record::DataEnd(_) => break,
            _ => {}
        }
    }
    Ok(recording)
}

/// The recording again with episode number `index`.
fn renumbered(recording: Recording, index: u64, path: &Path) -> Result<Vec<u8>, ExportError> {
    let mut writer = super::writer::new_writer(&recording.library)?;
    for mut metadata in recording.metadata {
        if metadata.name == EPISODE_METADATA {
            metadata
                .metadata
                .insert("episode_index".into(), index.to_string());
        }
        writer
            .write_metadata(&metadata)
            .map_err(mcap_error("metadata"))?;
    }
    let mut schema_ids = BTreeMap::new();
    for (id, (name, encoding, data)) in &recording.schemas {
        let new = writer
            .add_schema(name, encoding, data)
            .map_err(mcap_error("schema"))?;
        schema_ids.insert(*id, new);
    }
    let mut channel_ids = BTreeMap::new();
    let mut info_channel = None;
    for (id, channel) in &recording.channels {
        let schema = schema_ids.get(&channel.schema_id).copied().unwrap_or(0);
        let new = writer
            .add_channel(
                schema,
                &channel.topic,
                &channel.message_encoding,
                &channel.metadata,
            )
            .map_err(mcap_error("channel"))?;
        channel_ids.insert(*id, new);
        if channel.topic == INFO_TOPIC {
            info_channel = Some(*id);
        }
    }
    for (mut header, data) in recording.messages {
        let mut data = data;
        if Some(header.channel_id) == info_channel {
            if let Some(problem) = crate::export::bounded::json_values_problem(&data) {
                return Err(ExportError::InvalidDataset {
                    path: path.to_path_buf(),
                    problem: format!("its {INFO_TOPIC} message {problem}"),
                });
            }
            let mut info: Value =
                serde_json::from_slice(&data).map_err(|e| ExportError::InvalidDataset {
                    path: path.to_path_buf(),
                    problem: format!("its {INFO_TOPIC} message is not JSON: {e}"),
                })?;
            info["episode_index"] = json!(index);
            data = info.to_string().into_bytes();
        }
        header.channel_id = channel_ids
            .get(&header.channel_id)
            .copied()
            .ok_or_else(|| ExportError::InvalidDataset {
                path: path.to_path_buf(),
                problem: format!(
                    "a message on channel {} it never declares",
                    header.channel_id
                ),
            })?;
        writer
            .write_to_known_channel(&header, &data)
            .map_err(mcap_error("message"))?;
    }
    writer.finish().map_err(mcap_error("summary"))?;
    Ok(writer.into_inner().into_inner())
}

/// Merges the request's MCAP folders into a new one at its `out` (see the module overview).
pub(super) fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let mut parts = Vec::new();
    for path in request.inputs {
        // MCAP folders keep no surgvla metadata file: the shard is in the recorded options.
        let manifest = path.join(MANIFEST);
        let options = RunOptions::from_manifest(&read_json(&manifest).map_err(read)?);
        let collection =
            (options.shard()).and_then(|shard| Collection::from_json(&json!({ SHARD_KEY: shard })));
        parts.push(Part::read(path, &manifest, collection)?);
    }
    let plan = plan(parts)?;
    let mut copy = |dir: &mut DatasetDir, root: &Path, from: u64, to: u64| {
        let source = root.join(file_of(from));
        let recording = read_recording(&source).map_err(read)?;
        let bytes = renumbered(recording, to, &source).map_err(read)?;
        dir.write_atomically(&file_of(to), &bytes).map_err(write)?;
        Ok(())
    };
    merge_episode_files(request, &plan, EPISODES, &file_of, &mut copy, &[], MANIFEST)
}
