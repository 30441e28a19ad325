//! What every format's checks report into: [`Findings`] (kept per check, counted past
//! [`FINDINGS_PER_CHECK`]), each naming file, episode, frame and check; the [`Report`] they
//! become; the [`Facts`] `info` prints; and the checks every format shares: the manifest
//! ([`check_manifest`]) and the semantics of our own datasets ([`check_semantics`]). The
//! formats and the dispatcher (`validate`) import this module; it imports no format.

use crate::episode::{Aabb, Episode, GripperEncoding};
use crate::export::bounded::read_json;
use crate::export::check::Check;
use crate::export::collection::Collection;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
/// Findings kept per check before the rest are only counted (a defect repeated on 40,000 frames
/// is one problem).
pub const FINDINGS_PER_CHECK: usize = 20;

/// How much a dataset holds, as its checks counted it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub episodes: u64,
    pub frames: u64,
}

impl From<(u64, u64)> for Counts {
    /// (episodes, frames).
    fn from((episodes, frames): (u64, u64)) -> Self {
        Counts { episodes, frames }
    }
}

/// One defect (or, as a warning, one oddity): where it is and what is wrong. Ordered by place
/// (file, episode, frame), then check and message: the order of a report.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub struct Finding {
    /// The file, relative to the dataset's root where it is inside it.
    pub file: Option<String>,
    pub episode: Option<u64>,
    pub frame: Option<u64>,
    /// The check that found it.
    pub check: Check,
    pub message: String,
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut place = Vec::new();
        if let Some(file) = &self.file {
            place.push(file.clone());
        }
        if let Some(episode) = self.episode {
            place.push(format!("episode {episode}"));
        }
        if let Some(frame) = self.frame {
            place.push(format!("frame {frame}"));
        }
        if place.is_empty() {
            write!(f, "[{}] {}", self.check, self.message)
        } else {
            write!(f, "{}: [{}] {}", place.join(", "), self.check, self.message)
        }
    }
}

/// What [`crate::export::validate::validate`] found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    pub valid: bool,
    /// The layout found, as the format names it ("lerobot-v3.0", "rlds", "ply", ...).
    pub format: &'static str,
    /// The folder or file that was checked (an RLDS version folder when given its data dir).
    pub path: PathBuf,
    pub episodes: u64,
    pub frames: u64,
    /// Bytes on disk of every file under the path.
    pub bytes: u64,
    /// What the dataset is, as far as the checks learned it (for `info`).
    pub facts: Facts,
    pub errors: Vec<Finding>,
    pub warnings: Vec<Finding>,
    /// The quality lint's verdict, one line per check that ran (empty: not linted).
    pub lint: Vec<LintSummary>,
    /// Every episode a finding names (all of them, not only the findings listed), with
    /// whether one of its findings is an error: what `edit --drop flagged` drops.
    #[serde(skip)]
    pub flagged: BTreeMap<u64, bool>,
}

impl Report {
    /// Adds errors found by another check (e.g. `validate --replay`).
    pub fn add_errors(&mut self, errors: Vec<Finding>) {
        self.valid &= errors.is_empty();
        self.errors.extend(errors);
    }
}

/// One check's verdict in one line (`surgvla validate` prints one per check that ran).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LintSummary {
    pub check: Check,
    /// "ok", "warning" or "error".
    pub status: &'static str,
    pub line: String,
}

impl std::fmt::Display for LintSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:<20} {:<7} {}",
            self.check.name(),
            self.status,
            self.line
        )
    }
}

/// What a dataset is: what `surgvla info` prints besides the counts.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Facts {
    pub fps: Option<f64>,
    pub robot_type: Option<String>,
    /// Features (or arrays, or topics) with dtype and shape.
    pub features: Vec<FeatureFact>,
    /// Episodes per task (language instruction), when known.
    pub tasks: BTreeMap<String, u64>,
    /// Episodes per surgvla task id, with the instructions they were given (one task id may
    /// have several: paraphrases, T2-3's colours; two ids may share one: T1-1 and T2-1), when
    /// the dataset records its episodes' task ids.
    pub task_ids: BTreeMap<String, TaskIdFact>,
    /// The program that wrote it, when it says.
    pub generator: Option<String>,
    /// How surgvla collected it (seed, tasks, options); None (null in JSON) when not ours.
    pub collection: Option<Collection>,
}

/// One surgvla task id's episodes and instructions (see [`Facts::task_ids`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TaskIdFact {
    pub episodes: u64,
    pub instructions: std::collections::BTreeSet<String>,
}

/// One feature as declared.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FeatureFact {
    pub name: String,
    pub dtype: String,
    pub shape: Vec<usize>,
}

/// How thoroughly to check.
#[derive(Clone, Debug, Default)]
pub struct ValidateOptions {
    /// Metadata, every row's numbers, and one frame per row group or video file instead of
    /// every frame.
    pub quick: bool,
    /// Step limit per task id (e.g. "T1-1" -> 100) for the semantic checks of our datasets;
    /// empty: not checked.
    pub step_limits: BTreeMap<String, usize>,
    /// Worker threads for the full pass (0: one per core).
    pub threads: usize,
    /// Run the quality lint ([`crate::export::lint`]).
    pub lint: bool,
    /// A community's contribution guide to check against too.
    pub profile: Option<Profile>,
}

/// A contribution guide `validate --profile` checks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Profile {
    /// Open-H-Embodiment's (LeRobot v2.1 video, features, splits, README, rates).
    OpenH,
}

/// Collects findings from checks that may run in parallel, keeping [`FINDINGS_PER_CHECK`] of
/// each check and counting the rest.
#[derive(Debug)]
pub struct Findings {
    root: PathBuf,
    inner: Mutex<Collected>,
    facts: Mutex<Facts>,
    lint: Mutex<Vec<LintSummary>>,
}

/// Findings as the checks report them (in parallel, in any order): per (check, is_error), the
/// [`FINDINGS_PER_CHECK`] first in place order (file, episode, frame, message) and the count of
/// all, so that the report is the same whatever order the threads ran in.
#[derive(Debug, Default)]
struct Collected {
    kept: BTreeMap<(Check, bool), std::collections::BTreeSet<Finding>>,
    /// Episode -> whether an error names it (see [`Report::flagged`]).
    flagged: BTreeMap<u64, bool>,
    /// (check, is_error) -> findings seen.
    counts: BTreeMap<(Check, bool), usize>,
}

/// Where a finding is: file, episode, frame.
#[derive(Clone, Debug, Default)]
pub struct At {
    pub file: Option<String>,
    pub episode: Option<u64>,
    pub frame: Option<u64>,
}

impl At {
    pub fn file(file: impl Into<String>) -> Self {
        At {
            file: Some(file.into()),
            ..At::default()
        }
    }

    pub fn episode(mut self, episode: u64) -> Self {
        self.episode = Some(episode);
        self
    }

    pub fn frame(mut self, frame: u64) -> Self {
        self.frame = Some(frame);
        self
    }
}

impl Findings {
    pub fn new(root: &Path) -> Self {
        Findings {
            root: root.to_path_buf(),
            inner: Mutex::new(Collected::default()),
            facts: Mutex::new(Facts::default()),
            lint: Mutex::new(Vec::new()),
        }
    }

    /// Records what the checks learned about the dataset.
    pub fn learn(&self, update: impl FnOnce(&mut Facts)) {
        update(&mut self.facts.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// Records a lint check's one-line verdict.
    pub fn summarise(&self, summary: LintSummary) {
        (self.lint.lock().unwrap_or_else(|e| e.into_inner())).push(summary);
    }

    /// `path` relative to the dataset's root where it is inside it.
    pub fn relative(&self, path: &Path) -> String {
        path.strip_prefix(&self.root)
            .unwrap_or(path)
            .to_string_lossy()
            .into_owned()
    }

    pub fn error(&self, at: At, check: Check, message: impl Into<String>) {
        self.add(true, at, check, message.into());
    }

    pub fn warning(&self, at: At, check: Check, message: impl Into<String>) {
        self.add(false, at, check, message.into());
    }

    /// An error about the file at `path`.
    pub fn file_error(&self, path: &Path, check: Check, message: impl Into<String>) {
        self.error(At::file(self.relative(path)), check, message);
    }

    fn add(&self, is_error: bool, at: At, check: Check, message: String) {
        let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let count = inner.counts.entry((check, is_error)).or_default();
        *count += 1;
        if let Some(episode) = at.episode {
            *inner.flagged.entry(episode).or_default() |= is_error;
        }
        let finding = Finding {
            file: at.file,
            episode: at.episode,
            frame: at.frame,
            check,
            message,
        };
        let kept = inner.kept.entry((check, is_error)).or_default();
        kept.insert(finding);
        if kept.len() > FINDINGS_PER_CHECK {
            kept.pop_last();
        }
    }

    pub fn has_errors(&self) -> bool {
        let inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        inner.kept.keys().any(|(_, is_error)| *is_error)
    }

    /// The report, with one more finding per check that had more than it kept.
    pub fn into_report(self, format: &'static str, counts: Counts) -> Report {
        let Counts { episodes, frames } = counts;
        let mut inner = self.inner.into_inner().unwrap_or_else(|e| e.into_inner());
        let (mut errors, mut warnings) = (Vec::new(), Vec::new());
        let listed: BTreeMap<(Check, bool), usize> = inner
            .kept
            .iter()
            .map(|(key, kept)| (*key, kept.len()))
            .collect();
        for ((_, is_error), kept) in std::mem::take(&mut inner.kept) {
            if is_error {
                errors.extend(kept);
            } else {
                warnings.extend(kept);
            }
        }
        errors.sort();
        warnings.sort();
        for ((check, is_error), count) in std::mem::take(&mut inner.counts) {
            // Identical findings are listed once; the rest of a check's are counted.
            let shown = listed.get(&(check, is_error)).copied().unwrap_or(0);
            if count > shown {
                let finding = Finding {
                    file: None,
                    episode: None,
                    frame: None,
                    check,
                    message: format!(
                        "{} more like the above not listed ({count} in all)",
                        count - shown
                    ),
                };
                if is_error {
                    errors.push(finding);
                } else {
                    warnings.push(finding);
                }
            }
        }
        let bytes = disk_bytes(&self.root);
        Report {
            valid: errors.is_empty(),
            format,
            episodes,
            frames,
            bytes,
            facts: self.facts.into_inner().unwrap_or_else(|e| e.into_inner()),
            path: self.root,
            errors,
            warnings,
            lint: self.lint.into_inner().unwrap_or_else(|e| e.into_inner()),
            flagged: inner.flagged,
        }
    }
}

/// Bytes of every file under `path` (the file's size for a file).
pub fn disk_bytes(path: &Path) -> u64 {
    bytes_where(path, &|_| true)
}

/// Bytes of the files under `path` (or of `path`, a file) that `wanted` takes; a symbolic link
/// counts as itself, never followed.
pub fn bytes_where(path: &Path, wanted: &dyn Fn(&Path) -> bool) -> u64 {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => std::fs::read_dir(path)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| bytes_where(&e.path(), wanted))
            .sum(),
        Ok(m) if wanted(path) => m.len(),
        _ => 0,
    }
}

/// Verifies the manifest `relative` when the dataset has one: every listed file present with
/// its recorded size and CRC-32C (`quick`: the CRC of the metadata files only, `meta/` and the
/// root's JSON; the others by size), and no listed path outside the root. Returns whether another
/// tool rewrote the dataset since (its own metadata changed: the manifest is stale, a warning).
pub fn check_manifest(root: &Path, relative: &str, quick: bool, findings: &Findings) -> bool {
    let path = root.join(relative);
    if !path.is_file() {
        return false;
    }
    let manifest = match read_json(&path) {
        Ok(manifest) => manifest,
        Err(_) => {
            findings.file_error(&path, Check::Manifest, "is not valid JSON");
            return false;
        }
    };
    let Some(files) = manifest["files"].as_array() else {
        findings.file_error(&path, Check::Manifest, "has no files list");
        return false;
    };
    let mut changed: Vec<(String, String)> = Vec::new();
    for file in files {
        let record: crate::export::dir::FileRecord = match serde_json::from_value(file.clone()) {
            Ok(record) => record,
            Err(_) => {
                findings.file_error(
                    &path,
                    Check::Manifest,
                    format!("has a malformed entry {file}"),
                );
                continue;
            }
        };
        let listed = match crate::export::paths::relative(&record.path) {
            Ok(listed) => listed,
            Err(problem) => {
                findings.file_error(
                    &path,
                    Check::Manifest,
                    format!(
                        "lists {:?}, which cannot be a path inside the dataset: it {problem}",
                        record.path
                    ),
                );
                continue;
            }
        };
        let metadata = record.path.starts_with("meta/") || !record.path.contains('/');
        let problem = if quick && !metadata {
            record.size_problem(&root.join(listed))
        } else {
            record.problem(&root.join(listed))
        };
        match problem {
            Ok(None) => {}
            Ok(Some(problem)) => changed.push((record.path.clone(), problem)),
            Err(_) => findings.error(
                At::file(record.path.clone()),
                Check::Readable,
                "cannot be read",
            ),
        }
    }
    report_changed(root, relative, changed, findings)
}

/// The files that no longer match the manifest `relative`: checksum errors, or, when the
/// dataset's own metadata is among them (another tool rewrote it), one warning that the
/// manifest is stale; returns whether it is.
fn report_changed(
    root: &Path,
    relative: &str,
    changed: Vec<(String, String)>,
    findings: &Findings,
) -> bool {
    // A dataset whose metadata another tool rewrote (lerobot-edit-dataset edits in place): the
    // manifest is stale, not the files damaged; their content is judged by the other checks.
    // Rewritten, not broken: the metadata is a readable JSON file still.
    let rewritten = (changed.iter()).any(|(path, _)| {
        REWRITTEN_BY_OTHERS.contains(&path.as_str()) && read_json(&root.join(path)).is_ok()
    });
    if rewritten {
        let names: Vec<&str> = changed
            .iter()
            .map(|(path, _)| path.as_str())
            .take(5)
            .collect();
        findings.warning(
            At::file(relative),
            Check::Manifest,
            format!(
                "is stale: {} of the files it lists changed since surgvla wrote them ({}{}), the dataset's own metadata among them: another tool rewrote the dataset, and its files are judged on their content",
                changed.len(),
                names.join(", "),
                if changed.len() > names.len() { ", ..." } else { "" }
            ),
        );
        return true;
    }
    for (path, problem) in changed {
        findings.error(
            At::file(path),
            Check::Checksum,
            format!("{problem} (per {relative})"),
        );
    }
    false
}

/// The metadata a tool that edits a dataset in place rewrites (lerobot's `info.json`): when it
/// no longer matches our manifest, the manifest is stale rather than the files damaged.
const REWRITTEN_BY_OTHERS: [&str; 1] = ["meta/info.json"];

/// What our own datasets promise beyond their format, from their surgvla metadata.
#[derive(Clone, Debug, Default)]
pub struct Semantics {
    /// How `action[6]` is encoded; None: not ours, gripper not checked.
    pub gripper: Option<GripperEncoding>,
    /// The tool tip's box; states must stay inside it (with a millimetre of slack).
    pub tip_workspace: Option<Aabb>,
    /// Step limit per task id.
    pub step_limits: BTreeMap<String, usize>,
}

impl Semantics {
    /// The semantics of a dataset whose surgvla metadata is `surgvla` (`Null`: none).
    pub fn of(surgvla: &serde_json::Value, options: &ValidateOptions) -> Option<Self> {
        if surgvla.is_null() {
            return None;
        }
        let collection = Collection::from_json(&surgvla["collection"]);
        let gripper = collection.and_then(|c| c.gripper_encoding());
        let tip_workspace = serde_json::from_value::<Aabb>(serde_json::json!({
            "min_m": surgvla["tip_workspace_m"]["min"],
            "max_m": surgvla["tip_workspace_m"]["max"],
        }))
        .ok();
        Some(Semantics {
            gripper,
            tip_workspace,
            step_limits: options.step_limits.clone(),
        })
    }
}

/// Slack on the workspace box: states are measured, the box bounds commands.
const WORKSPACE_SLACK_M: f64 = 0.002;

/// What our own datasets promise beyond their format, per decoded episode: the gripper
/// encoding, states inside the workspace, the task's step limit and provenance. (Steps present,
/// finite numbers and a non-empty instruction are each format's own content checks.)
pub fn check_semantics(episode: &Episode, semantics: &Semantics, at: &At, findings: &Findings) {
    let index = episode.meta.index;
    let here = || at.clone().episode(index);
    if let Some(encoding) = semantics.gripper {
        let allowed: &[f32] = match encoding {
            GripperEncoding::Continuous => &[0.0, 1.0],
            GripperEncoding::Pulse => &[-1.0, 0.0, 1.0],
        };
        for (frame, step) in episode.steps.iter().enumerate() {
            if !allowed.contains(&step.action[6]) {
                findings.error(
                    here().frame(frame as u64),
                    Check::Gripper,
                    format!(
                        "action gripper value {} is not one of {allowed:?} ({encoding:?} encoding)",
                        step.action[6]
                    ),
                );
            }
        }
    }
    if let Some(workspace) = semantics.tip_workspace {
        let grown = workspace.grown(WORKSPACE_SLACK_M);
        for (frame, step) in episode.steps.iter().enumerate() {
            let tip = [0, 1, 2].map(|i| f64::from(step.state[i]));
            if !grown.contains(tip) {
                findings.error(
                    here().frame(frame as u64),
                    Check::Workspace,
                    format!(
                        "the tool tip {tip:?} m is outside the workspace {:?}..{:?}",
                        workspace.min_m, workspace.max_m
                    ),
                );
            }
        }
    }
    if episode.meta.task_code.is_empty() {
        findings.error(
            here(),
            Check::Provenance,
            "no task id (surgvla/task_id) recorded for the episode",
        );
    } else if let Some(&limit) = semantics.step_limits.get(&episode.meta.task_code) {
        if episode.steps.len() > limit {
            findings.error(
                here(),
                Check::StepLimit,
                format!(
                    "{} steps, more than {}'s limit of {limit}",
                    episode.steps.len(),
                    episode.meta.task_code
                ),
            );
        }
    } else if !semantics.step_limits.is_empty() {
        findings.error(
            here(),
            Check::Provenance,
            format!("unknown task id {}", episode.meta.task_code),
        );
    }
    if episode.meta.attempts == 0 {
        findings.error(
            here(),
            Check::Provenance,
            "no attempt count (surgvla/attempts) recorded for the episode",
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_is_the_same_whatever_order_the_checks_ran_in() {
        let report = |order: &[u64]| {
            let findings = Findings::new(Path::new("/nowhere"));
            for &i in order {
                let at = At::file(format!("data/file-{:03}.parquet", i % 7)).episode(i);
                findings.error(at, Check::Timestamps, format!("frame {i} is late"));
                findings.warning(
                    At::file("meta/info.json"),
                    Check::VideoDecode,
                    "not decoded",
                );
            }
            let report = findings.into_report("lerobot-v3.0", Counts::default());
            serde_json::to_string(&(report.errors, report.warnings)).unwrap()
        };
        let forward: Vec<u64> = (0..100).collect();
        let mut shuffled = forward.clone();
        let mut rng = crate::rng::SplitMix64::new(7);
        for i in (1..shuffled.len()).rev() {
            shuffled.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
        }
        assert_eq!(report(&forward), report(&shuffled));
        let text = report(&forward);
        // 20 kept, then the count of the rest.
        assert!(
            text.contains("80 more like the above not listed (100 in all)"),
            "{text}"
        );
        assert!(text.contains("99 more like the above"), "{text}");
    }
}
