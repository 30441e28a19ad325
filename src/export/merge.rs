//! What every format's merge shares: each input's recorded options (its manifest's `options`,
//! [`RunOptions::from_manifest`]) checked to agree on everything that shapes the bytes, shards put
//! in shard order, the merged dataset's collection ("0/1" once all N of N are there, so it
//! equals the single run) and options, and the merged collect report. LeRobot's merge
//! (`lerobot/merge.rs`) checks its inputs its own way (its datasets may come from other tools);
//! the others start from [`plan`]: RLDS re-encodes its records through its writer, zarr re-packs
//! its chunks, point-cloud folders copy their files under new episode numbers.

use crate::export::bounded::read_json;
use crate::export::collection::{Collection, RecordedShard, Shard};
use crate::export::convert::ConvertError;
use crate::export::dir::DatasetDir;
use crate::export::dir::RunOptions;
use crate::export::error::ExportError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::pipeline::{Episodes, in_order};
use crate::export::sink::EpisodeSink;
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// The report file `collect` leaves in a dataset, merged when every input has one.
pub const REPORT: &str = "collect_report.json";

/// One input as a merge sees it before reading its episodes.
#[derive(Clone, Debug)]
pub struct Part {
    /// The path the user gave.
    pub path: PathBuf,
    /// How its episodes were made (None when it does not say).
    pub collection: Option<Collection>,
    /// What shaped its bytes, from its manifest.
    pub options: RunOptions,
}

impl Part {
    /// An input whose manifest is `manifest` (the file every surgvla dataset ends with); one
    /// without recorded options (written by an older surgvla) cannot be checked, so it is refused.
    pub fn read(
        path: &Path,
        manifest: &Path,
        collection: Option<Collection>,
    ) -> Result<Part, MergeError> {
        let read = |e| MergeError::Convert(crate::export::convert::ConvertError::Read(e));
        let options = RunOptions::from_manifest(&read_json(manifest).map_err(read)?);
        if options.format().is_none() {
            return Err(MergeError::Unsupported {
                path: manifest.to_path_buf(),
                problem:
                    "records no options (written by an older surgvla): write it again to merge it"
                        .into(),
            });
        }
        Ok(Part {
            path: path.to_path_buf(),
            collection,
            options,
        })
    }

    fn shard(&self) -> Option<Shard> {
        self.collection.as_ref()?.shard()?.part()
    }
}

/// The inputs in the order their episodes go, and what the merged dataset records.
#[derive(Debug)]
pub struct Plan {
    pub parts: Vec<Part>,
    /// The merged collection (its shard "0/1" when all N of N are merged).
    pub collection: Option<Collection>,
    /// The merged dataset's options (the inputs' with the merged shard).
    pub options: RunOptions,
}

impl Plan {
    /// The shard the merged dataset records (None: its inputs record none).
    pub fn shard(&self) -> Option<RecordedShard> {
        self.collection.as_ref()?.shard()
    }
}

/// Checks `parts` agree on every option but the shard (naming each that differs), puts shards
/// in shard order (the same shard twice is refused) and says what the merged dataset records.
pub fn plan(mut parts: Vec<Part>) -> Result<Plan, MergeError> {
    let first = parts.first().ok_or(MergeError::NoInput)?.clone();
    let without_shard = |options: &RunOptions| {
        let mut options = options.clone();
        options.set_shard(None);
        options
    };
    for part in &parts[1..] {
        let changes = without_shard(&first.options).changes(&without_shard(&part.options));
        if !changes.is_empty() {
            let reasons: Vec<String> = changes.iter().map(ToString::to_string).collect();
            return Err(MergeError::Incompatible {
                path: part.path.clone(),
                first: first.path.clone(),
                reasons: reasons.join("; "),
            });
        }
    }
    let shards: Option<Vec<Shard>> = parts.iter().map(Part::shard).collect();
    let mut collection = first.collection.clone();
    let mut options = first.options.clone();
    if let Some(mut shards) = shards {
        parts.sort_by_key(|p| p.shard().map(|s| (s.count, s.index)));
        shards.sort_by_key(|s| (s.count, s.index));
        for pair in parts.windows(2) {
            if let Some(shard) = pair[0].shard()
                && pair[1].shard() == Some(shard)
            {
                return Err(MergeError::Incompatible {
                    path: pair[1].path.clone(),
                    first: pair[0].path.clone(),
                    reasons: format!("both are shard \"{shard}\""),
                });
            }
        }
        let merged = RecordedShard::merged(&shards);
        if let Some(collection) = &mut collection {
            collection.set_shard(&merged);
        }
        options.set_shard(Some(&merged));
    }
    Ok(Plan {
        parts,
        collection,
        options,
    })
}

/// Every episode of `sources` in turn, numbered on from 0, into `sink` in batches on `threads`
/// worker threads (0: one per core), then the sink finished, with the inputs' merged collect
/// report when `reports` has them; a resumed sink skips the episodes it holds. `progress`
/// hears the episodes done so far.
pub fn write_through(
    sources: Vec<Box<dyn EpisodeSource + Send>>,
    sink: &mut (dyn EpisodeSink + Send),
    threads: usize,
    reports: Option<(Vec<Value>, Option<RecordedShard>)>,
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let pool = crate::threads::pool(threads).map_err(|e| write(e.into()))?;
    let mut sources = sources;
    let sources = sources.iter_mut().map(|s| &mut **s as _).collect();
    let mut episodes = Episodes::of(sources)
        .renumbered()
        .skipping(sink.next_episode_index());
    let mut write_batch =
        |batch: Vec<crate::episode::Episode>| sink.write_batch(&batch).map_err(write);
    pool.install(|| in_order(&mut episodes, read, &mut write_batch, progress))?;
    match reports {
        Some((reports, shard)) => {
            let mut sidecar = |summary: &Summary| {
                report_bytes(&reports, summary, shard.as_ref()).map(|file| vec![file])
            };
            sink.finish_with(Some(&mut sidecar))
        }
        None => sink.finish(),
    }
    .map_err(write)
}

/// A folder of files per episode (point clouds, MCAP) read for a merge: its `episodes.jsonl`
/// lines in order, each checked to number its episode in turn and state its frames.
pub fn episode_lines(root: &Path, jsonl: &str) -> Result<Vec<(Value, u64)>, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let path = root.join(jsonl);
    let mut episodes = Vec::new();
    for line in crate::export::bounded::lines(&path).map_err(read)? {
        let (_, line) = line.map_err(read)?;
        if line.trim().is_empty() {
            continue;
        }
        let invalid = |problem: String| {
            read(ExportError::InvalidDataset {
                path: path.clone(),
                problem: format!("line {}: {problem}", episodes.len() + 1),
            })
        };
        let value: Value =
            serde_json::from_str(&line).map_err(|e| invalid(format!("is not JSON: {e}")))?;
        if value["episode_index"].as_u64() != Some(episodes.len() as u64) {
            return Err(invalid(format!(
                "episode_index is {}, expected {}",
                value["episode_index"],
                episodes.len()
            )));
        }
        let Some(frames) = value["frames"].as_u64().filter(|&f| f > 0) else {
            return Err(invalid("has no frame count".into()));
        };
        episodes.push((value, frames));
    }
    Ok(episodes)
}

/// What a files-per-episode merge does with one episode: copy (or re-pack) its files from
/// `root`'s episode `from` into `dir` as episode `to`.
pub type CopyEpisode<'a> =
    dyn FnMut(&mut DatasetDir, &Path, u64, u64) -> Result<(), MergeError> + 'a;

/// Merges folders of files per episode (the plan's order): each episode copied by `copy`, its
/// `episodes.jsonl` line again with the new index (and `file`, when the line names one, from
/// `file_of`), then `metadata` files, the manifest `manifest`, the merged collect report, and
/// the folder marked complete. Every input's lines are read before anything is written.
pub fn merge_episode_files(
    request: &mut MergeRequest<'_>,
    plan: &Plan,
    jsonl: &str,
    file_of: &dyn Fn(u64) -> String,
    copy: &mut CopyEpisode<'_>,
    metadata: &[(&str, Vec<u8>)],
    manifest: &str,
) -> Result<Summary, MergeError> {
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let inputs: Vec<(&Path, Vec<(Value, u64)>)> = plan
        .parts
        .iter()
        .map(|p| Ok((p.path.as_path(), episode_lines(&p.path, jsonl)?)))
        .collect::<Result<_, MergeError>>()?;
    let mut dir = output_dir(request.out, request.resume, &plan.options).map_err(write)?;
    let mut lines = Vec::new();
    let (mut episodes, mut frames) = (0u64, 0u64);
    for (root, input) in &inputs {
        for (k, (line, count)) in input.iter().enumerate() {
            copy(&mut dir, root, k as u64, episodes)?;
            let mut line = line.clone();
            line["episode_index"] = episodes.into();
            if line.get("file").is_some() {
                line["file"] = file_of(episodes).into();
            }
            lines.extend_from_slice(line.to_string().as_bytes());
            lines.push(b'\n');
            episodes += 1;
            frames += count;
        }
        (request.progress)(episodes);
    }
    dir.write_atomically(jsonl, &lines).map_err(write)?;
    for (relative, bytes) in metadata {
        dir.write_atomically(relative, bytes).map_err(write)?;
    }
    if let Some(card) = merged_card(plan)? {
        dir.write_atomically(crate::export::card::CARD, &card)
            .map_err(write)?;
    }
    let roots: Vec<&Path> = inputs.iter().map(|(root, _)| *root).collect();
    finish_folder(dir, manifest, (episodes, frames), &roots, plan)
}

/// The output folder of a merge that keeps no checkpoint (zarr, MCAP, PLY, PCD): created, or
/// with `resume` and an interrupted merge there (started with the same options), emptied and
/// written again from the start. A merge is a function of its inputs, so a resumed one ends
/// with the bytes of an uninterrupted run; these merges copy or re-pack without encoding, so
/// starting over costs little.
pub fn output_dir(
    out: &Path,
    resume: bool,
    options: &crate::export::dir::RunOptions,
) -> Result<DatasetDir, crate::export::error::ExportError> {
    if crate::export::dir::resumes(out, resume) {
        let (dir, _) = DatasetDir::resume::<serde::de::IgnoredAny>(out, options, &[""])?;
        Ok(dir)
    } else {
        DatasetDir::create(out, options)
    }
}

/// Ends a merge that writes its folder itself: the manifest `manifest` over every file
/// written, the inputs' (`roots`) collect reports merged beside it when they all have one, the
/// folder marked complete; the summary of `(episodes, frames)` and the files.
pub fn finish_folder(
    mut dir: DatasetDir,
    manifest: &str,
    (episodes, frames): (u64, u64),
    roots: &[&Path],
    plan: &Plan,
) -> Result<Summary, MergeError> {
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let mut summary = Summary {
        episodes,
        frames,
        files: dir.files().len() as u64,
        bytes: dir.files().iter().map(|f| f.bytes).sum(),
    };
    summary.bytes += dir.write_manifest(manifest).map_err(write)?;
    summary.files += 1;
    if let Some(reports) = reports(roots) {
        let (relative, bytes) =
            report_bytes(&reports, &summary, plan.shard().as_ref()).map_err(write)?;
        dir.write_unlisted(&relative, &bytes).map_err(write)?;
    }
    dir.complete().map_err(write)?;
    Ok(summary)
}

/// The merged dataset's card, for merges that write their folders themselves: the first
/// input's card with every input's tally added up and the merged shard
/// ([`crate::export::card::retally`]); None when an input has no card of ours (a dataset
/// written before cards: the merged one has none either).
pub fn merged_card(plan: &Plan) -> Result<Option<Vec<u8>>, MergeError> {
    use crate::export::card::{CARD, Tally, parse, retally};
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let mut first = None;
    let mut tally = Tally::default();
    for part in &plan.parts {
        let path = part.path.join(CARD);
        if !path.is_file() {
            return Ok(None);
        }
        let bytes = crate::export::bounded::read_metadata(&path).map_err(read)?;
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let Some(part_tally) = parse(&text) else {
            return Ok(None);
        };
        tally.extend(&part_tally);
        first.get_or_insert(text);
    }
    let shard = plan.shard();
    Ok(first
        .and_then(|card| retally(&card, &tally, shard.as_ref()))
        .map(String::into_bytes))
}

/// The inputs' collect reports merged (see [`merge_reports`]) when every input has one.
pub fn reports(paths: &[&Path]) -> Option<Vec<Value>> {
    paths
        .iter()
        .map(|p| read_json(&p.join(REPORT)).ok())
        .collect()
}

/// The merged report's bytes, as the dataset's sidecar.
pub fn report_bytes(
    reports: &[Value],
    summary: &Summary,
    shard: Option<&RecordedShard>,
) -> Result<(String, Vec<u8>), ExportError> {
    let report = merge_reports(reports, summary, shard);
    let bytes = serde_json::to_vec_pretty(&report).map_err(|source| ExportError::Json {
        path: REPORT.into(),
        source,
    })?;
    Ok((REPORT.to_string(), bytes))
}

/// One collect report of several: counts summed per task (in order of first appearance),
/// rates recomputed, failures concatenated, the slot range spanning them all, the merged
/// dataset's summary, timings summed.
pub fn merge_reports(reports: &[Value], summary: &Summary, shard: Option<&RecordedShard>) -> Value {
    let mut merged = reports.first().cloned().unwrap_or(Value::Null);
    let sum = |key: &str| -> u64 { reports.iter().filter_map(|r| r[key].as_u64()).sum() };
    let mut tasks: Vec<Value> = Vec::new();
    for report in reports {
        for task in report["tasks"].as_array().into_iter().flatten() {
            match tasks.iter_mut().find(|t| t["code"] == task["code"]) {
                Some(total) => {
                    for key in [
                        "episodes",
                        "frames",
                        "attempts",
                        "expert_successes",
                        "replay_failures",
                    ] {
                        let value =
                            total[key].as_u64().unwrap_or(0) + task[key].as_u64().unwrap_or(0);
                        total[key] = value.into();
                    }
                }
                None => tasks.push(task.clone()),
            }
        }
    }
    for task in &mut tasks {
        let attempts = task["attempts"].as_u64().unwrap_or(0);
        let successes = task["expert_successes"].as_u64().unwrap_or(0);
        task["expert_success_rate"] = if attempts > 0 {
            (successes as f64 / attempts as f64).into()
        } else {
            0.0.into()
        };
    }
    let failures: Vec<Value> = reports
        .iter()
        .flat_map(|r| r["failures"].as_array().cloned().unwrap_or_default())
        .collect();
    let range = |k: usize| {
        reports
            .iter()
            .filter_map(move |r| r["slot_range"][k].as_u64())
    };
    merged["shard"] = shard.map_or(Value::Null, |shard| shard.to_string().into());
    merged["slot_range"] = json!([range(0).min(), range(1).max()]);
    merged["episodes"] = sum("episodes").into();
    merged["frames"] = sum("frames").into();
    merged["tasks"] = tasks.into();
    merged["failures"] = failures.into();
    merged["resumed_at_episode"] = Value::Null;
    merged["dataset"] = serde_json::to_value(summary).unwrap_or(Value::Null);
    merged["merged_from"] = reports.len().into();
    let wall: f64 = reports
        .iter()
        .filter_map(|r| r["timing"]["wall_secs"].as_f64())
        .sum();
    merged["timing"] = json!({"wall_secs_summed_over_inputs": wall});
    merged
}

#[cfg(test)]
mod tests {
    use super::*;

    fn part(name: &str, shard: &str, seed: u64) -> Part {
        let collection = Collection::from_json(&json!({"seed": seed, "shard": shard}));
        let mut options = RunOptions::recorded(&json!({"format": "zarr"}));
        if let Some(collection) = &collection {
            options.merge(RunOptions::recorded(collection));
        }
        Part {
            path: PathBuf::from(name),
            collection,
            options,
        }
    }

    #[test]
    fn all_shards_merge_back_to_one_run_in_shard_order() {
        let plan = plan(vec![part("b", "1/2", 0), part("a", "0/2", 0)]).expect("plan");
        let order: Vec<&Path> = plan.parts.iter().map(|p| p.path.as_path()).collect();
        assert_eq!(order, [Path::new("a"), Path::new("b")]);
        assert_eq!(plan.shard().map(|s| s.to_string()).as_deref(), Some("0/1"));
        assert_eq!(plan.options, part("x", "0/1", 0).options);
    }

    #[test]
    fn some_shards_say_which_and_repeats_or_other_options_are_refused() {
        let plan = plan(vec![part("a", "0/3", 0), part("c", "2/3", 0)]).expect("plan");
        assert_eq!(
            plan.shard().map(|s| s.to_string()).as_deref(),
            Some("merged 0/3,2/3")
        );
        let twice = super::plan(vec![part("a", "0/2", 0), part("b", "0/2", 0)]);
        assert!(twice.unwrap_err().to_string().contains("both are shard"));
        let seed = super::plan(vec![part("a", "0/2", 0), part("b", "1/2", 7)]);
        let message = seed.unwrap_err().to_string();
        assert!(message.contains("seed"), "{message}");
        assert!(!message.contains("shard"), "{message}");
    }
}
