//! Running an edit: [`plan`] reads the input's episodes' metadata (and validate's findings when
//! a selector asks for them), chooses what is kept and where it goes, and states each output
//! ([`Planned`]); [`write`] writes one output through the input format's own writer, its
//! video copied sample for sample; [`dry_run`] says what would be written; [`verify`] reads
//! an output back against the input.

use super::picked::{Changes, Picked, Uncopyable};
use super::plan::{Chosen, Selection, choose};
use crate::episode::ImageEncoding;
use crate::export::convert::ConvertError;
use crate::export::error::ExportError;
use crate::export::format::{Format, SinkOptions};
use crate::export::info::DatasetInfo;
use crate::export::open::ConvertInput;
use crate::export::sink::Summary;
use crate::export::source::{EpisodeSource, SourceOptions};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What `edit` is asked (the CLI's flags, typed).
#[derive(Clone, Debug, Default)]
pub struct EditRequest {
    pub input: PathBuf,
    /// What the input may not say (another tool's RLDS: fps, robot type).
    pub source: SourceOptions,
    pub out: PathBuf,
    pub selection: Selection,
    /// Splits go into the one output's `splits` (LeRobot's info.json), episodes grouped by
    /// split, instead of one dataset per split under `out`.
    pub splits_in_info: bool,
    /// Features left out (`--remove-feature`), as `convert --without` names them.
    pub remove: Vec<String>,
    pub changes: Changes,
    /// Encode again the video of episodes that cannot be copied (`--allow-reencode`).
    pub allow_reencode: bool,
    /// Video statistics recomputed from decoded frames where the input carries only
    /// per-episode summaries (`--exact-stats`).
    pub exact_stats: bool,
}

/// One dataset an edit writes.
pub struct Output {
    /// Its split's name (None: the one output).
    pub split: Option<String>,
    pub path: PathBuf,
    /// Input episodes, in the output's order.
    pub order: Vec<u64>,
    /// The output's description (features renamed, splits, the edit in its identity).
    pub info: DatasetInfo,
}

/// An edit planned: the input's format and options, what was chosen, the outputs.
pub struct Planned {
    pub format: Format,
    pub options: Arc<dyn SinkOptions>,
    pub chosen: Chosen,
    pub outputs: Vec<Output>,
    /// Steps of every input episode, by input index.
    pub steps: Vec<u64>,
    /// Files another tool wrote beside the data, carried into every output.
    pub carried: Vec<(String, Vec<u8>)>,
    request: EditRequest,
}

fn usage(problem: String) -> ConvertError {
    ConvertError::Input(ExportError::InvalidOptions(problem))
}

impl EditRequest {
    /// What `convert` would read of the input for `options`: the features removed.
    fn reading(&self) -> ConvertInput {
        ConvertInput {
            path: self.input.clone(),
            source: self.source.clone(),
            without: self.remove.clone(),
            ..ConvertInput::default()
        }
    }
}

/// Plans `request` (see the module overview): the user's mistakes (a format edit does not
/// write, a field no episode has, a feature to rename the input lacks) are refused before
/// anything is written.
pub fn plan(request: &EditRequest) -> Result<Planned, ConvertError> {
    let (format, found) =
        crate::export::registry::detect_readable(&request.input).map_err(ConvertError::Read)?;
    let source = crate::export::open::open_source_with(&found.root, &request.source)
        .map_err(ConvertError::Read)?;
    let options: Arc<dyn SinkOptions> = match format.options_like(&found, source.info()) {
        Some(options) => Arc::from(options.map_err(ConvertError::Read)?),
        None => {
            return Err(usage(format!(
                "edit writes its result in the input's own format, and surgvla cannot write {} like {} (convert it first)",
                format.title(),
                found.root.display()
            )));
        }
    };
    if request.splits_in_info && !format.records_splits() {
        return Err(usage(format!(
            "--splits-in-info records the splits in one dataset's metadata, which {} has no place for: leave it out to write one dataset per split",
            format.title()
        )));
    }
    let carried = format.carried_files(&found).map_err(ConvertError::Read)?;
    // The input as the outputs read it (features removed): its episodes listed, its info.
    let mut reading = request.reading().open(options.as_ref())?;
    let mut listed = Vec::with_capacity(reading.len() as usize);
    while let Some(skimmed) = reading.skim() {
        listed.push(skimmed.map_err(ConvertError::Read)?);
    }
    let wants_findings = (request.selection.keep.iter())
        .chain(&request.selection.drop)
        .any(|s| s.wants_findings());
    let flagged = if wants_findings {
        flagged(&found.root)?
    } else {
        BTreeMap::new()
    };
    let chosen = choose(&listed, &request.selection, &flagged).map_err(usage)?;
    let mut info = reading.info().clone();
    request.changes.apply_to_info(&mut info).map_err(usage)?;
    let outputs = outputs(request, &chosen, &info);
    if outputs.iter().all(|o| o.order.is_empty()) {
        return Err(usage(format!(
            "the edit keeps none of the input's {} episodes",
            listed.len()
        )));
    }
    Ok(Planned {
        format,
        options,
        chosen,
        outputs,
        steps: listed.iter().map(|e| e.steps).collect(),
        carried,
        request: request.clone(),
    })
}

/// Every episode `validate --lint` names in a finding, with whether an error does.
fn flagged(root: &Path) -> Result<BTreeMap<u64, bool>, ConvertError> {
    let options = crate::export::validate::ValidateOptions {
        lint: true,
        ..Default::default()
    };
    let report = crate::export::validate::validate(root, &options).map_err(ConvertError::Read)?;
    Ok(report.flagged)
}

/// The outputs of `chosen`: one dataset at `out`, or one per split under it, or one with the
/// splits in its metadata.
fn outputs(request: &EditRequest, chosen: &Chosen, info: &DatasetInfo) -> Vec<Output> {
    let identity = |order: &[u64]| {
        let bytes: Vec<u8> = order.iter().flat_map(|i| i.to_le_bytes()).collect();
        format!(
            "{}; edit: {} episodes (crc32c {:08x}), {:?}, reencode {}, exact stats {}",
            info.input.as_deref().unwrap_or_default(),
            order.len(),
            crc32c::crc32c(&bytes),
            request.changes,
            request.allow_reencode,
            request.exact_stats
        )
    };
    let total = chosen.kept.len() + chosen.dropped.len();
    let with = |order: Vec<u64>, splits: Vec<(String, std::ops::Range<u64>)>| {
        let mut info = info.clone();
        info.input = Some(identity(&order));
        info.history.push(history(request, order.len(), total));
        info.splits = splits;
        (order, info)
    };
    if request.selection.splits.is_none() {
        // The input's own splits, as they fall in the episodes kept.
        let kept = &chosen.kept;
        let before = |i: u64| kept.partition_point(|k| *k < i) as u64;
        let splits = (info.splits.iter())
            .map(|(name, r)| (name.clone(), before(r.start)..before(r.end)))
            .filter(|(_, r)| !r.is_empty())
            .collect();
        let (order, info) = with(kept.clone(), splits);
        return vec![Output {
            split: None,
            path: request.out.clone(),
            order,
            info,
        }];
    }
    if request.splits_in_info {
        let mut order = Vec::new();
        let mut splits = Vec::new();
        for (name, members) in &chosen.outputs {
            let from = order.len() as u64;
            order.extend_from_slice(members);
            splits.push((name.clone().unwrap_or_default(), from..order.len() as u64));
        }
        let (order, info) = with(order, splits);
        return vec![Output {
            split: None,
            path: request.out.clone(),
            order,
            info,
        }];
    }
    (chosen.outputs.iter())
        .map(|(name, members)| {
            let name = name.clone().unwrap_or_default();
            let range = 0..members.len() as u64;
            let (order, info) = with(members.clone(), vec![(name.clone(), range)]);
            Output {
                path: request.out.join(&name),
                split: Some(name),
                order,
                info,
            }
        })
        .collect()
}

/// The card's sentence on an edit that wrote `episodes` of the input's `total`.
fn history(request: &EditRequest, episodes: usize, total: usize) -> String {
    let mut said = vec![format!(
        "Edited with `surgvla edit`: {episodes} of the input's {total} episodes"
    )];
    let selection = &request.selection;
    let selectors: Vec<String> = (selection.keep.iter().map(|s| format!("--keep {s}")))
        .chain(selection.drop.iter().map(|s| format!("--drop {s}")))
        .collect();
    if !selectors.is_empty() {
        said.push(format!("chosen by `{}`", selectors.join(" ")));
    }
    if let Some(splits) = &selection.splits {
        said.push(format!("split `{splits}` (seed {})", selection.seed));
    }
    if !request.remove.is_empty() {
        said.push(format!("without {}", request.remove.join(", ")));
    }
    let changes = &request.changes;
    for (old, new) in &changes.renames {
        said.push(format!("`{old}` renamed `{new}`"));
    }
    if let Some(task) = &changes.set_task {
        said.push(format!("every instruction set to \"{task}\""));
    }
    for (old, new) in &changes.task_map {
        said.push(format!("\"{old}\" replaced by \"{new}\""));
    }
    format!("{}.", said.join("; "))
}

impl Planned {
    /// The source of output `k`'s episodes: the input, chosen and changed; `leave_stored`:
    /// their rows left in the input's files where the writer can copy them (for writing, not
    /// for comparing pixels).
    pub fn source(&self, k: usize, leave_stored: bool) -> Result<Picked, ConvertError> {
        let output = &self.outputs[k];
        let reading = self.request.reading();
        let options = self.options.clone();
        let exact = self.request.exact_stats;
        let open: super::picked::Opener = Box::new(move || {
            let mut source = reading.open(options.as_ref()).map_err(|e| match e {
                ConvertError::Read(e) | ConvertError::Write(e) | ConvertError::Input(e) => e,
            })?;
            // The output is the input's format: what the edit does not change is copied as
            // stored where the source can leave it so.
            if leave_stored {
                source.leave_rows_stored();
            }
            Ok(if exact {
                Box::new(ExactStats::new(source)) as Box<dyn EpisodeSource + Send>
            } else {
                source
            })
        });
        let uncopyable = if self.request.allow_reencode {
            Uncopyable::Reencode {
                quality: self.reencode_quality(),
            }
        } else {
            Uncopyable::Refuse
        };
        Picked::new(
            open,
            output.order.clone(),
            output.info.clone(),
            self.request.changes.clone(),
            uncopyable,
        )
        .map_err(ConvertError::Read)
    }

    /// The quality an episode's video is encoded again at: its codec's default.
    fn reencode_quality(&self) -> u32 {
        (self.outputs[0].info.features.iter())
            .find_map(|f| f.video)
            .map_or(0, crate::media::video::Codec::default_quality)
    }

    /// Writes output `k` (or, `resume`, continues it) on `threads` worker threads; `progress`
    /// hears the episodes written. Returns its summary and the episodes whose video was encoded
    /// again, (output index, feature).
    pub fn write(
        &self,
        k: usize,
        threads: usize,
        resume: bool,
        progress: &mut (dyn FnMut(u64) + Send),
    ) -> Result<(Summary, Vec<(u64, String)>), ConvertError> {
        let output = &self.outputs[k];
        let mut source = self.source(k, true)?;
        let reencoded = source.reencoded();
        let mut sink = crate::export::open::open_sink(
            &output.path,
            &output.info,
            self.options.as_ref(),
            resume,
        )
        .map_err(ConvertError::Write)?;
        sink.carry_files(self.carried.clone());
        let summary =
            crate::export::convert::convert(&mut source, sink.as_mut(), threads, progress)?;
        let reencoded = reencoded.lock().unwrap_or_else(|e| e.into_inner()).clone();
        Ok((summary, reencoded))
    }

    /// Reads output `k` back and compares every frame with the input's (video copied: sample
    /// bytes; video encoded again: decoded, within the lossy tolerance); the differences.
    pub fn verify(&self, k: usize, reencoded: bool) -> Result<Vec<String>, ConvertError> {
        let output = &self.outputs[k];
        let mut source = self.source(k, false)?;
        if !reencoded {
            let summary = Summary::default();
            return crate::export::verify::verify_output(&mut source, &output.path, &summary);
        }
        let mut target = crate::export::open::open_source(&output.path)
            .and_then(crate::export::decoded::Decoded::new)
            .map_err(ConvertError::Write)?;
        let mut decoded =
            crate::export::decoded::Decoded::new(Box::new(source)).map_err(ConvertError::Read)?;
        Ok(crate::export::convert::verify_within(
            &mut decoded,
            &mut target,
            Some(crate::export::convert::LOSSY_RGB_MIN_PSNR_DB),
        )?
        .differences)
    }
}

/// A source whose video features get exact statistics from their decoded frames where the
/// input carries only a summary (`edit --exact-stats`).
struct ExactStats {
    inner: Box<dyn EpisodeSource + Send>,
}

impl ExactStats {
    fn new(inner: Box<dyn EpisodeSource + Send>) -> Self {
        ExactStats { inner }
    }
}

impl Iterator for ExactStats {
    type Item = Result<crate::episode::Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let episode = self.inner.next()?;
        Some(episode.and_then(|mut e| {
            crate::export::decoded::exact_video_stats(&mut e, self.inner.info())?;
            Ok(e)
        }))
    }
}

impl EpisodeSource for ExactStats {
    fn info(&self) -> &DatasetInfo {
        self.inner.info()
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.inner.skip_episode()
    }

    fn drop_stored(&mut self, unused: &[ImageEncoding]) {
        self.inner.drop_stored(unused);
    }

    fn leave_rows_stored(&mut self) {
        self.inner.leave_rows_stored();
    }

    fn taking_only(&mut self, episodes: std::sync::Arc<std::collections::BTreeSet<u64>>) {
        self.inner.taking_only(episodes);
    }
}

/// What [`dry_run`] found: per output, its episodes, frames, estimated bytes, and the
/// episodes whose video would be encoded again.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DryRun {
    pub outputs: Vec<DryOutput>,
}

/// One output of a [`DryRun`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DryOutput {
    pub path: PathBuf,
    pub episodes: u64,
    pub frames: u64,
    /// Video sample bytes copied, plus the input's other bytes in proportion to the frames.
    pub estimated_bytes: u64,
    /// Input episodes whose video cannot be copied as it is.
    pub reencode: Vec<u64>,
}

/// Says what [`Planned::write`] would write, reading the kept episodes' video sample tables
/// and sizes (nothing decoded, nothing written). The input's bytes besides video are
/// attributed to the outputs by their share of its frames.
pub fn dry_run(planned: &Planned) -> Result<DryRun, ConvertError> {
    let total_frames: u64 = planned.steps.iter().sum();
    let input_bytes = crate::export::findings::disk_bytes(&planned.request.input);
    let mut per_episode: BTreeMap<u64, (u64, bool)> = BTreeMap::new();
    let mut source = planned.request.reading().open(planned.options.as_ref())?;
    // Nothing here needs the frame rows' images.
    source.leave_rows_stored();
    // Without video there is nothing to copy sample by sample or to encode again.
    let wanted: std::collections::BTreeSet<u64> =
        if crate::export::decoded::Decoded::needed(source.info()) {
            (planned.outputs.iter())
                .flat_map(|o| o.order.iter().copied())
                .collect()
        } else {
            Default::default()
        };
    source.taking_only(Arc::new(wanted.clone()));
    let mut index = 0u64;
    while wanted.last().is_some_and(|last| index <= *last) {
        let item = if wanted.contains(&index) {
            source.next().map(|e| e.map(Some))
        } else {
            source.skip_episode().map(|r| r.map(|()| None))
        };
        let Some(item) = item else { break };
        if let Some(episode) = item.map_err(ConvertError::Read)? {
            let video: Vec<_> = (episode.encoded.iter())
                .filter(|e| matches!(e.encoding, ImageEncoding::Video(_)))
                .collect();
            let bytes: u64 = (video.iter())
                .flat_map(|e| e.frames.iter().map(|f| f.data.len() as u64))
                .sum();
            per_episode.insert(index, (bytes, video.iter().any(|e| e.shown.is_some())));
        }
        index += 1;
    }
    let video_total = crate::export::findings::bytes_where(&planned.request.input, &|p| {
        p.extension().is_some_and(|e| e == "mp4")
    });
    let other_bytes = input_bytes.saturating_sub(video_total);
    let outputs = (planned.outputs.iter())
        .map(|output| {
            let frames: u64 = (output.order.iter())
                .map(|i| planned.steps.get(*i as usize).copied().unwrap_or(0))
                .sum();
            let video: u64 = (output.order.iter())
                .map(|i| per_episode.get(i).map_or(0, |e| e.0))
                .sum();
            let share = if total_frames == 0 {
                0
            } else {
                (other_bytes as u128 * frames as u128 / total_frames as u128) as u64
            };
            DryOutput {
                path: output.path.clone(),
                episodes: output.order.len() as u64,
                frames,
                estimated_bytes: video + share,
                reencode: (output.order.iter().copied())
                    .filter(|i| per_episode.get(i).is_some_and(|e| e.1))
                    .collect(),
            }
        })
        .collect();
    Ok(DryRun { outputs })
}

/// Whether `path` holds a finished dataset: a folder with files and no interrupted run's
/// marker (a resumed edit passes over the splits it finished).
pub fn is_complete(path: &Path) -> bool {
    std::fs::read_dir(path).is_ok_and(|mut d| d.next().is_some())
        && !path.join(crate::export::dir::INCOMPLETE_MARKER).exists()
}
