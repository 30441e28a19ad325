//! Validating MCAP recordings (one file, or a folder of them): magic, chunk CRCs, the summary
//! with its statistics and chunk indexes, every message decodable as its channel says: a
//! protobuf channel's schema named `foxglove.<Name>`, a JSON channel's messages valid JSON that
//! satisfies the channel's JSON Schema, and message counts matching the summary. An episode is a
//! file; a frame is an `/endoscope/rgb` message.

use crate::export::check::Check;
use crate::export::findings::{At, FeatureFact, Findings, ValidateOptions, check_manifest};
use crate::export::schema;
use mcap::read::{MessageStream, Options, Summary};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Checks one recording; returns its `/endoscope/rgb` message count.
fn check_file(path: &Path, episode: u64, quick: bool, findings: &Findings) -> u64 {
    let at = || At::file(findings.relative(path)).episode(episode);
    // A recording is one episode: far below 4 GiB.
    let Ok(bytes) = crate::export::bounded::read_capped(path, 4 << 30) else {
        findings.error(at(), Check::Readable, "cannot be read");
        return 0;
    };
    let summary = check_summary(&bytes, &at, episode, findings);
    // Quick mode walks the same records, chunk CRCs and counts (so it never calls valid what
    // the full pass refuses), and skips only each message's content (JSON Schema, names).
    // The mcap reader reserves each chunk's claimed uncompressed size before decompressing it.
    if let Some(problem) = chunks_problem(&bytes) {
        findings.error(at(), Check::Chunk, problem);
        return 0;
    }
    let stream = match MessageStream::new_with_options(&bytes, Options::ValidateChunkCrcs.into()) {
        Ok(stream) => stream,
        Err(error) => {
            findings.error(at(), Check::Magic, format!("is not an MCAP file: {error}"));
            return 0;
        }
    };
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    let mut json_schemas: BTreeMap<u16, Option<serde_json::Value>> = BTreeMap::new();
    let mut frames = 0u64;
    for message in stream {
        let message = match message {
            Ok(message) => message,
            Err(error) => {
                findings.error(
                    at(),
                    Check::Crc,
                    format!(
                        "reading stops after {} messages: {error}",
                        counts.values().sum::<u64>()
                    ),
                );
                return frames;
            }
        };
        let channel = &message.channel;
        *counts.entry(channel.id).or_default() += 1;
        if channel.topic == "/endoscope/rgb" {
            frames += 1;
        }
        if quick {
            continue;
        }
        if channel.message_encoding == "json" {
            check_json_message(&message, &mut json_schemas, || at().frame(frames), findings);
        } else if channel.message_encoding == "protobuf"
            && channel
                .schema
                .as_ref()
                .is_some_and(|s| !s.name.starts_with("foxglove."))
        {
            findings.error(
                at(),
                Check::SchemaName,
                format!("{} uses a schema not named foxglove.<Name>", channel.topic),
            );
        }
    }
    if let Some(stats) = summary.as_ref().and_then(|s| s.stats.as_ref()) {
        let total: u64 = counts.values().sum();
        if stats.message_count != total {
            findings.error(
                at(),
                Check::Summary,
                format!(
                    "the statistics count {} messages, the file holds {total}",
                    stats.message_count
                ),
            );
        }
    }
    frames
}

/// Largest uncompressed chunk accepted (the writer's chunks are about 1 MiB; other tools'
/// rarely exceed tens of MiB).
const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// A little-endian u64 at `at`, if the bytes hold one.
fn u64_at(bytes: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(
        bytes.get(at..at.checked_add(8)?)?.try_into().ok()?,
    ))
}

/// The first record in `bytes` (from `at`) whose length runs past the end: its offset, opcode
/// and claimed length. Stops at the footer.
fn overlong_record(bytes: &[u8], mut at: usize) -> Option<(usize, u8, u64)> {
    const FOOTER: u8 = 0x02;
    while let Some(&opcode) = bytes.get(at) {
        let length = u64_at(bytes, at + 1)?;
        let end = usize::try_from(length)
            .ok()
            .and_then(|length| (at + 9).checked_add(length))
            .filter(|end| *end <= bytes.len());
        match end {
            None => return Some((at, opcode, length)),
            Some(_) if opcode == FOOTER => return None,
            Some(end) => at = end,
        }
    }
    None
}

/// What the mcap reader would allocate unchecked (it reserves a chunk's claimed uncompressed
/// size, and each record's claimed length inside a chunk): a chunk claiming more than
/// [`MAX_CHUNK_BYTES`], an uncompressed chunk whose size disagrees with its records, or a record
/// inside a chunk running past the chunk's end. Top-level records cut short, and chunks that do
/// not decompress, are left to the reader, which reports them.
pub(super) fn chunks_problem(bytes: &[u8]) -> Option<String> {
    const MAGIC_LEN: usize = 8;
    const CHUNK: u8 = 0x06;
    let mut at = MAGIC_LEN;
    while let (Some(&opcode), Some(length)) = (bytes.get(at), u64_at(bytes, at + 1)) {
        let body = at + 9;
        let end = usize::try_from(length).ok()?.checked_add(body)?;
        let record = bytes.get(body..end)?;
        if opcode == CHUNK {
            let uncompressed = u64_at(record, 16)?;
            if uncompressed > MAX_CHUNK_BYTES {
                return Some(format!(
                    "the chunk at byte {at} claims {uncompressed} bytes uncompressed, over the {MAX_CHUNK_BYTES} accepted"
                ));
            }
            let name_len = u32::from_le_bytes(record.get(28..32)?.try_into().ok()?) as usize;
            let compression = record.get(32..32 + name_len)?;
            let records_len = usize::try_from(u64_at(record, 32 + name_len)?).ok()?;
            let start = 40 + name_len;
            let compressed = record.get(start..start.checked_add(records_len)?)?;
            let inner = match compression {
                b"" => std::borrow::Cow::Borrowed(compressed),
                b"zstd" => std::borrow::Cow::Owned(
                    zstd::bulk::decompress(compressed, uncompressed as usize).ok()?,
                ),
                _ => return None,
            };
            if inner.len() as u64 != uncompressed {
                return Some(format!(
                    "the chunk at byte {at} claims {uncompressed} bytes uncompressed and holds {}",
                    inner.len()
                ));
            }
            if let Some((offset, opcode, length)) = overlong_record(&inner, 0) {
                return Some(format!(
                    "a record (opcode {opcode:#04x}) at byte {offset} of the chunk at byte {at} claims {length} bytes, past the chunk's end"
                ));
            }
        }
        at = end;
    }
    None
}

/// The summary section read and checked (statistics, chunk indexes, Foxglove schema names);
/// the first episode's channels are what `info` prints.
fn check_summary(
    bytes: &[u8],
    at: &dyn Fn() -> At,
    episode: u64,
    findings: &Findings,
) -> Option<Summary> {
    let summary = match Summary::read(bytes) {
        Ok(Some(summary)) => Some(summary),
        Ok(None) => {
            findings.error(
                at(),
                Check::Summary,
                "has no summary section (no indexes or statistics)",
            );
            None
        }
        Err(error) => {
            findings.error(
                at(),
                Check::Summary,
                format!("the summary cannot be read: {error}"),
            );
            None
        }
    };
    if let Some(summary) = &summary
        && episode == 0
    {
        findings.learn(|facts| {
            let mut channels: Vec<_> = summary.channels.values().collect();
            channels.sort_by(|a, b| a.topic.cmp(&b.topic));
            facts.features = channels
                .iter()
                .map(|c| FeatureFact {
                    name: c.topic.clone(),
                    dtype: c
                        .schema
                        .as_ref()
                        .map_or_else(|| c.message_encoding.clone(), |s| s.name.clone()),
                    shape: Vec::new(),
                })
                .collect();
        });
    }
    if let Some(summary) = &summary {
        if summary.stats.is_none() {
            findings.error(at(), Check::Summary, "has no statistics record");
        }
        if summary.chunk_indexes.is_empty() {
            findings.error(at(), Check::Summary, "has no chunk indexes");
        }
        for schema in summary.schemas.values() {
            if schema.encoding == "protobuf" && !schema.name.starts_with("foxglove.") {
                findings.error(
                    at(),
                    Check::SchemaName,
                    format!(
                        "protobuf schema {} is not a foxglove.<Name> well-known schema",
                        schema.name
                    ),
                );
            }
        }
    }
    summary
}

/// A JSON message: valid JSON, and valid against its schema (our channels against
/// `schemas/mcap_json_channels.json`, others against their own channel's JSON Schema, compiled
/// once per channel in `schemas`).
fn check_json_message(
    message: &mcap::Message<'_>,
    schemas: &mut BTreeMap<u16, Option<serde_json::Value>>,
    at: impl Fn() -> At,
    findings: &Findings,
) {
    let channel = &message.channel;
    if let Some(problem) = crate::export::bounded::json_values_problem(&message.data) {
        findings.error(
            at(),
            Check::Json,
            format!("a {} message {problem}", channel.topic),
        );
        return;
    }
    let value: serde_json::Value = match serde_json::from_slice(&message.data) {
        Ok(value) => value,
        Err(_) => {
            findings.error(
                at(),
                Check::Json,
                format!("a {} message is not JSON", channel.topic),
            );
            return;
        }
    };
    // Our channels against schemas/, others against their own channel's schema.
    let schema = schemas.entry(channel.id).or_insert_with(|| {
        let ours = channel
            .schema
            .as_ref()
            .is_some_and(|s| s.name.starts_with("surgvla."));
        let built_in = serde_json::from_str::<serde_json::Value>(schema::MCAP_JSON_CHANNELS)
            .ok()
            .and_then(|all| all.get(&channel.topic).cloned())
            .filter(|_| ours);
        built_in.or_else(|| {
            channel
                .schema
                .as_ref()
                .filter(|s| s.encoding == "jsonschema")
                .and_then(|s| serde_json::from_slice(&s.data).ok())
        })
    });
    if let Some(schema) = schema {
        for (pointer, problem) in schema::check(&value, schema) {
            findings.error(
                at(),
                Check::JsonSchema,
                format!("{} message {pointer} {problem}", channel.topic),
            );
        }
    }
}

/// Checks the MCAP file or folder at `root`; returns (episodes, frames).
pub fn check(root: &Path, options: &ValidateOptions, findings: &Findings) -> (u64, u64) {
    let files: Vec<PathBuf> = if root.is_file() {
        vec![root.to_path_buf()]
    } else {
        check_manifest(root, super::writer::MANIFEST, options.quick, findings);
        let mut files: Vec<PathBuf> = std::fs::read_dir(root)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
            .collect();
        files.sort();
        files
    };
    let frames: Vec<u64> = files
        .par_iter()
        .enumerate()
        .map(|(i, path)| check_file(path, i as u64, options.quick, findings))
        .collect();
    if !root.is_file() {
        check_episode_lines(root, &files, &frames, findings);
    }
    (files.len() as u64, frames.iter().sum())
}

/// A folder's `episodes.jsonl` (when there is one) against its recordings: a line per file in
/// order, each naming its file and episode, and the frames the file holds.
fn check_episode_lines(root: &Path, files: &[PathBuf], frames: &[u64], findings: &Findings) {
    let path = root.join("episodes.jsonl");
    if !path.is_file() {
        return;
    }
    let lines = match crate::export::bounded::lines(&path) {
        Ok(lines) => lines,
        Err(error) => {
            findings.file_error(&path, Check::Episodes, error.to_string());
            return;
        }
    };
    let mut count = 0usize;
    for line in lines {
        let at = || At::file(findings.relative(&path)).episode(count as u64);
        let text = match line {
            Ok((_, text)) => text,
            Err(error) => {
                findings.error(at(), Check::Episodes, error.to_string());
                return;
            }
        };
        let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
            findings.error(
                at(),
                Check::Episodes,
                format!("line {} is not JSON", count + 1),
            );
            count += 1;
            continue;
        };
        let name = files
            .get(count)
            .and_then(|f| f.file_name())
            .map(|n| n.to_string_lossy().into_owned());
        if value["episode_index"].as_u64() != Some(count as u64) {
            findings.error(
                at(),
                Check::Episodes,
                format!("line {} does not say episode {count}", count + 1),
            );
        } else if value["file"].as_str() != name.as_deref() {
            findings.error(
                at(),
                Check::Episodes,
                format!("names {}, the recording is {name:?}", value["file"]),
            );
        } else if value["frames"].as_u64() != frames.get(count).copied() {
            findings.error(
                at(),
                Check::Episodes,
                format!(
                    "says {} frames, the recording holds {}",
                    value["frames"], frames[count]
                ),
            );
        }
        count += 1;
    }
    if count != files.len() {
        findings.file_error(
            &path,
            Check::Episodes,
            format!("has {count} lines for {} recordings", files.len()),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record: opcode, u64 length, body.
    fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut out = vec![opcode];
        out.extend_from_slice(&(body.len() as u64).to_le_bytes());
        out.extend_from_slice(body);
        out
    }

    /// A file of one uncompressed chunk holding `inner`, claiming `uncompressed` bytes.
    fn file(inner: &[u8], uncompressed: u64) -> Vec<u8> {
        let mut chunk = vec![0u8; 16];
        chunk.extend_from_slice(&uncompressed.to_le_bytes());
        chunk.extend_from_slice(&[0u8; 4]); // CRC
        chunk.extend_from_slice(&0u32.to_le_bytes()); // compression: none
        chunk.extend_from_slice(&(inner.len() as u64).to_le_bytes());
        chunk.extend_from_slice(inner);
        let mut out = b"\x89MCAP0\r\n".to_vec();
        out.extend(record(0x06, &chunk));
        out.extend(record(0x02, &[0u8; 20]));
        out
    }

    #[test]
    fn chunks_the_reader_would_overallocate_for_are_refused() {
        let inner = record(0x05, &[1, 2, 3]);
        assert_eq!(chunks_problem(&file(&inner, inner.len() as u64)), None);
        let huge = chunks_problem(&file(&inner, 1 << 50)).expect("refused");
        assert!(huge.contains("over the"), "{huge}");
        let disagree = chunks_problem(&file(&inner, 5)).expect("refused");
        assert!(disagree.contains("holds"), "{disagree}");
        let mut lying = record(0x05, &[1, 2, 3]);
        lying[1..9].copy_from_slice(&(1u64 << 55).to_le_bytes());
        let past = chunks_problem(&file(&lying, lying.len() as u64)).expect("refused");
        assert!(past.contains("past the chunk's end"), "{past}");
    }
}
