//! The dataset card: `README.md` in the dataset root, in the shape of lerobot's own cards (YAML
//! front matter with `license` (surgvla's simulated data only: another tool's or a robot's data
//! carries its owner's licence, which surgvla does not know), `task_categories: [robotics]`,
//! `tags`, `configs` where the format
//! has data files a hub viewer loads), then what the dataset is, its tasks with their episode
//! counts and instructions, its features with dtypes and shapes, how it was made (from the
//! metadata: the generator, the collection options and seed, the success rules), and how to cite
//! it (surgvla's data: surgvla and the benchmark; anyone else's: its own authors). The same content for every format and a pure function of the dataset: the writer core
//! tallies each episode into a journal (resumable like every journal) and writes the card before
//! the manifest, which lists it; merges that write their folders themselves add up their inputs'
//! cards ([`parse`]). `validate` checks a card against the dataset when there is one
//! ([`check`]); an older dataset without one gets a warning, never a finding.

use crate::episode::Episode;
use crate::export::check::Check;
use crate::export::collection::RecordedShard;
use crate::export::findings::{At, Findings};
use crate::export::info::DatasetInfo;
use serde_json::{Value, json};
use std::fmt::Write as _;

/// The card's file, in the dataset root.
pub const CARD: &str = "README.md";
/// The writer core's hidden journal of one line per episode: task, level, frames, instruction.
pub const TALLY_JOURNAL: &str = ".surgvla-card.jsonl";

/// One task's episodes as the card counts them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TaskTally {
    /// The task's id ("T1-1"), or its instruction in a dataset another tool made.
    pub task: String,
    pub level: u8,
    pub episodes: u64,
    pub frames: u64,
    /// The instructions its episodes were given, each once, in order of first use.
    pub instructions: Vec<String>,
}

/// What the card says of a dataset's episodes: its tasks in order of first appearance.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    pub tasks: Vec<TaskTally>,
}

impl Tally {
    /// The journal line of one episode.
    pub fn line(episode: &Episode) -> String {
        Tally::line_of(&episode.meta, episode.steps.len())
    }

    /// The journal line of an episode of `frames` frames.
    pub fn line_of(meta: &crate::episode::EpisodeMeta, frames: usize) -> String {
        json!({
            "task": task_key(&meta.task_code, &meta.instruction),
            "level": meta.level,
            "frames": frames,
            "instruction": meta.instruction,
        })
        .to_string()
    }

    /// Adds one journal line (lines that do not parse are skipped: the journal is ours).
    pub fn add_line(&mut self, line: &str) {
        let Ok(value) = serde_json::from_str::<Value>(line) else {
            return;
        };
        let text = |key: &str| value[key].as_str().unwrap_or_default().to_string();
        self.add(
            &text("task"),
            value["level"].as_u64().unwrap_or(0) as u8,
            1,
            value["frames"].as_u64().unwrap_or(0),
            &[text("instruction")],
        );
    }

    /// Adds `episodes` episodes of `task` holding `frames` frames in all.
    pub fn add(&mut self, task: &str, level: u8, episodes: u64, frames: u64, said: &[String]) {
        let index = match self.tasks.iter().position(|t| t.task == task) {
            Some(index) => index,
            None => {
                self.tasks.push(TaskTally {
                    task: task.to_string(),
                    level,
                    ..TaskTally::default()
                });
                self.tasks.len() - 1
            }
        };
        let entry = &mut self.tasks[index];
        entry.episodes += episodes;
        entry.frames += frames;
        for instruction in said {
            if !instruction.is_empty() && !entry.instructions.contains(instruction) {
                entry.instructions.push(instruction.clone());
            }
        }
    }

    /// Another dataset's tally after this one's (a merge).
    pub fn extend(&mut self, other: &Tally) {
        for task in &other.tasks {
            self.add(
                &task.task,
                task.level,
                task.episodes,
                task.frames,
                &task.instructions,
            );
        }
    }

    pub fn episodes(&self) -> u64 {
        self.tasks.iter().map(|t| t.episodes).sum()
    }

    pub fn frames(&self) -> u64 {
        self.tasks.iter().map(|t| t.frames).sum()
    }
}

fn task_key(code: &str, instruction: &str) -> String {
    if code.is_empty() {
        instruction.to_string()
    } else {
        code.to_string()
    }
}

/// What a format adds to its card: its name (a tag), the data files a hub viewer loads, and the
/// features it stores as video.
#[derive(Clone, Debug)]
pub struct CardFormat {
    /// As `--to` says it ("lerobot", "rlds", "zarr", "ply", "pcd", "mcap").
    pub name: &'static str,
    /// Whether the front matter's tags name the format (every card is tagged LeRobot, the
    /// hub's robotics tag, so LeRobot's own need not be).
    pub tagged: bool,
    /// A glob of the data files (`configs: data_files`), where the format has loadable ones.
    pub data_files: Option<&'static str>,
    /// How to load the dataset with its real client (Markdown: a sentence and a code block),
    /// where the format has one.
    pub loading: Option<String>,
    /// How the format stores depth (a sentence for the card's conventions).
    pub depth: &'static str,
    /// Features stored as video, with their codec's name (LeRobot's video mode).
    pub video: Vec<(String, &'static str)>,
}

/// A table cell: pipes and line breaks would break the table.
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace(['\n', '\r'], " ")
}

/// The card of a dataset: `info`, the tally of its episodes, its format.
pub fn render(info: &DatasetInfo, tally: &Tally, format: &CardFormat) -> String {
    let mut card = String::new();
    let ours = info.is_ours();
    // Front matter, in the keys and order lerobot's cards use.
    card.push_str("---\n");
    if ours {
        card.push_str("license: apache-2.0\n");
    }
    card.push_str("task_categories:\n- robotics\ntags:\n- LeRobot\n");
    if ours {
        card.push_str("- surgical\n- surgvla\n");
    }
    if format.tagged {
        let _ = writeln!(card, "- {}", format.name);
    }
    if let Some(files) = format.data_files {
        let _ = write!(
            card,
            "configs:\n- config_name: default\n  data_files: {files}\n"
        );
    }
    card.push_str("---\n\n");
    let title = if ours {
        "Surgical robot episodes (surgvla)"
    } else {
        "Robot episodes"
    };
    let _ = writeln!(card, "# {title}\n");
    let generator = if !info.generator.is_empty() {
        info.generator.clone()
    } else if !info.provenance.is_empty() {
        format!(
            "surgvla {} ingest from robot recordings",
            env!("CARGO_PKG_VERSION")
        )
    } else {
        "surgvla (converted from another tool's dataset)".to_string()
    };
    let _ = writeln!(
        card,
        "{} episodes, {} frames at {} frames per second of the `{}` robot, in the {} format, \
         written by {generator}. {SUMMARY_END}\n",
        tally.episodes(),
        tally.frames(),
        info.fps,
        info.robot_type,
        format.name,
    );
    card.push_str("## Tasks\n\n| task | level | episodes | frames | instructions |\n|---|---:|---:|---:|---|\n");
    card.push_str(&task_rows(tally));
    card.push_str(&feature_rows(info, format));
    card.push_str(&crate::export::conventions::loading(
        format.loading.as_deref(),
    ));
    card.push_str(&crate::export::conventions::conventions(info, format.depth));
    card.push_str(&how_made(info));
    let camera = &info.camera;
    if camera.fx_px > 0.0 {
        let _ = writeln!(
            card,
            "The camera: {} x {} pixels, fx {:.3} px, near {} m, far {} m; its intrinsics and `world_from_camera` are in the dataset's metadata.\n",
            camera.width_px, camera.height_px, camera.fx_px, camera.near_m, camera.far_m
        );
    }
    card.push_str(&citation(info, tally));
    card
}

/// The card's "How it was made" section: the collection's options, the paragraphs of the
/// ingest or conversion that made it, and how another tool's dataset was read.
fn how_made(info: &DatasetInfo) -> String {
    let mut card = String::new();
    card.push_str("\n## How it was made\n\n");
    match &info.collection {
        Some(collection) if !collection.is_empty() => {
            card.push_str("Recorded from surgvla's scripted experts in its simulator. The collection's options, as the dataset's surgvla metadata records them:\n\n");
            for (key, value) in collection.entries() {
                let _ = writeln!(card, "- `{}`: `{}`", cell(key), cell(&value.to_string()));
            }
            card.push('\n');
        }
        _ if !info.provenance.is_empty() => {
            for paragraph in &info.provenance {
                let _ = writeln!(card, "{paragraph}\n");
            }
        }
        _ => card.push_str("The dataset does not say how its episodes were made.\n\n"),
    }
    if !info.history.is_empty() {
        card.push_str("Then:\n\n");
        for step in &info.history {
            let _ = writeln!(card, "- {}", cell(step));
        }
        card.push('\n');
    }
    if !info.notes.is_empty() {
        card.push_str("How surgvla read the dataset it was converted from:\n\n");
        for note in &info.notes {
            let _ = writeln!(card, "- {}", cell(note));
        }
        card.push('\n');
    }
    card
}

/// The card's citation section: surgvla's and the benchmark's for the data it simulated, the
/// data's own authors' for anyone else's.
fn citation(info: &DatasetInfo, tally: &Tally) -> String {
    let mut card = String::new();
    let ours = info.is_ours();
    card.push_str("## Citation\n\n");
    if !ours {
        // Another tool's dataset or a robot's recordings: surgvla only converted them.
        card.push_str("Cite the data's own authors, as its source asks; surgvla converted it and adds no work of its own to cite. Its licence is its owner's: surgvla does not know it.\n");
        return card;
    }
    card.push_str("The tasks, experts and evaluation protocol are those of the SurgVLA-Bench benchmark (eight laparoscopic tasks in three levels, on the SurRoL simulator). Cite its paper when you use this dataset:\n\n");
    let _ = writeln!(
        card,
        "```bibtex\n{}\n```\n\nThe dataset itself:\n",
        crate::export::conventions::BENCHMARK_BIBTEX
    );
    let version = info.generator.strip_prefix("surgvla ").unwrap_or("unknown");
    let _ = write!(
        card,
        "```bibtex\n@software{{surgvla,\n  title = {{surgvla: datasets for surgical robot learning}},\n  version = {{{version}}},\n{}\n}}\n```\n",
        note(tally)
    );
    card
}

/// The features table, with its heading.
fn feature_rows(info: &DatasetInfo, format: &CardFormat) -> String {
    let mut card = String::new();
    card.push_str("\n## Features\n\n| feature | dtype | shape |\n|---|---|---|\n");
    for feature in &info.features {
        let dtype = match format.video.iter().find(|(name, _)| *name == feature.name) {
            Some((_, codec)) => format!("video ({codec})"),
            None => format!("{:?}", feature.dtype).to_lowercase(),
        };
        let shape: Vec<String> = feature.shape.iter().map(ToString::to_string).collect();
        let _ = writeln!(
            card,
            "| `{}` | {dtype} | [{}] |",
            cell(&feature.name),
            shape.join(", ")
        );
    }
    card
}

/// The end of the card's summary line (what [`retally`] finds it by).
const SUMMARY_END: &str = "Every count below is taken from its episodes.";

/// The tasks table's rows.
fn task_rows(tally: &Tally) -> String {
    let mut rows = String::new();
    for task in &tally.tasks {
        let instructions: Vec<String> = task.instructions.iter().map(|i| cell(i)).collect();
        let _ = writeln!(
            rows,
            "| {} | {} | {} | {} | {} |",
            cell(&task.task),
            task.level,
            task.episodes,
            task.frames,
            instructions.join("; ")
        );
    }
    rows
}

/// The citation's line with the counts.
fn note(tally: &Tally) -> String {
    format!(
        "  note = {{{} episodes, {} frames}}",
        tally.episodes(),
        tally.frames()
    )
}

/// The tally a card states (its tasks table), or None when the text holds no table of ours.
pub fn parse(card: &str) -> Option<Tally> {
    let table = card.split("## Tasks").nth(1)?;
    let mut tally = Tally::default();
    for line in table
        .lines()
        .skip_while(|l| !l.starts_with("| task"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
    {
        let cells: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
        let [task, level, episodes, frames, instructions] = cells[..] else {
            return None;
        };
        let unescape = |text: &str| text.replace("\\|", "|");
        let said: Vec<String> = if instructions.is_empty() {
            Vec::new()
        } else {
            instructions.split("; ").map(unescape).collect()
        };
        tally.add(
            &unescape(task),
            level.parse().ok()?,
            episodes.parse().ok()?,
            frames.parse().ok()?,
            &said,
        );
    }
    Some(tally)
}

/// A card again with another tally and shard (a merge whose format keeps no dataset info to
/// render one from: zarr, point-cloud and MCAP folders take their first input's): the summary
/// line, the tasks table, the `shard` option and the citation's counts replaced. None when the
/// text is not a card of ours.
pub fn retally(card: &str, tally: &Tally, shard: Option<&RecordedShard>) -> Option<String> {
    let mut out = String::with_capacity(card.len());
    let mut lines = card.lines().peekable();
    let mut seen_summary = false;
    while let Some(line) = lines.next() {
        if !seen_summary && line.ends_with(SUMMARY_END) {
            let (_, rest) = line.split_once(" frames at ")?;
            let _ = writeln!(
                out,
                "{} episodes, {} frames at {rest}",
                tally.episodes(),
                tally.frames()
            );
            seen_summary = true;
        } else if line.starts_with("| task | level |") {
            let _ = writeln!(out, "{line}");
            let _ = writeln!(out, "{}", lines.next()?);
            while lines.peek().is_some_and(|l| l.starts_with('|')) {
                lines.next();
            }
            out.push_str(&task_rows(tally));
        } else if line.starts_with("- `shard`: ")
            && let Some(shard) = shard
        {
            let quoted = Value::from(shard.to_string()).to_string();
            let _ = writeln!(out, "- `shard`: `{}`", cell(&quoted));
        } else if line.starts_with("  note = {") {
            let _ = writeln!(out, "{}", note(tally));
        } else {
            let _ = writeln!(out, "{line}");
        }
    }
    seen_summary.then_some(out)
}

/// What disagrees between a card's tally and the dataset's (episodes and frames in all, then
/// per task where both say), each as a sentence.
pub fn disagreements(card: &Tally, dataset_episodes: u64, dataset_frames: u64) -> Vec<String> {
    let mut found = Vec::new();
    if card.episodes() != dataset_episodes {
        found.push(format!(
            "says {} episodes, the dataset holds {dataset_episodes}",
            card.episodes()
        ));
    }
    if card.frames() != dataset_frames {
        found.push(format!(
            "says {} frames, the dataset holds {dataset_frames}",
            card.frames()
        ));
    }
    found
}

/// `validate`'s check of the card in `folder` (the dataset's folder) against the episodes and
/// frames the format's check counted: a card that disagrees, or is not one of ours, is an
/// error; a surgvla dataset without one (written before cards) a warning. A folder without a
/// surgvla manifest is another tool's, and its README.md its own.
pub fn check(folder: &std::path::Path, episodes: u64, frames: u64, findings: &Findings) {
    let ours = ["surgvla_manifest.json", "meta/surgvla_manifest.json"]
        .iter()
        .any(|m| folder.join(m).is_file());
    if !ours {
        return;
    }
    let at = || At::file(CARD.to_string());
    let path = folder.join(CARD);
    if !path.is_file() {
        findings.warning(
            at(),
            Check::Card,
            "the dataset has no card (README.md): written by a surgvla before cards",
        );
        return;
    }
    let Ok(bytes) = crate::export::bounded::read_metadata(&path) else {
        findings.error(at(), Check::Card, "cannot be read");
        return;
    };
    let Some(tally) = parse(&String::from_utf8_lossy(&bytes)) else {
        findings.error(at(), Check::Card, "has no tasks table of surgvla's");
        return;
    };
    for problem in disagreements(&tally, episodes, frames) {
        findings.error(at(), Check::Card, problem);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{Dtype, FeatureKind, FeatureSpec};

    fn info() -> DatasetInfo {
        let surgvla = json!({
            "generator": "surgvla 0.1.0",
            "collection": {"seed": 3, "tasks": ["T1-1", "T3-1"], "shard": "1/2"},
        });
        let features = vec![FeatureSpec {
            name: "observation.state".into(),
            kind: FeatureKind::State,
            dtype: Dtype::Float32,
            shape: vec![7],
            video: None,
            info: Default::default(),
            names: Vec::new(),
        }];
        DatasetInfo::from_surgvla_json(&surgvla, 5, "dvrk_psm", features)
    }

    fn tally() -> Tally {
        let mut tally = Tally::default();
        tally.add("T1-1", 1, 2, 70, &["pick up the gauze".into()]);
        tally.add(
            "T3-1",
            3,
            1,
            90,
            &["place it | there".into(), "put it down".into()],
        );
        tally
    }

    const LEROBOT: fn() -> CardFormat = || CardFormat {
        loading: None,
        depth: "",
        name: "lerobot",
        tagged: false,
        data_files: Some("data/*/*.parquet"),
        video: Vec::new(),
    };

    /// Another tool's data: no licence, no citation of surgvla (only its own authors), and the
    /// card still reads back.
    #[test]
    fn a_card_of_someone_elses_data_invents_no_licence_or_citation() {
        let mut foreign = info();
        foreign.generator = String::new();
        foreign.collection = None;
        let card = render(&foreign, &tally(), &LEROBOT());
        assert!(
            card.starts_with("---\ntask_categories:\n- robotics\n"),
            "{card}"
        );
        assert!(
            !card.contains("license") && !card.contains("@software"),
            "{card}"
        );
        assert!(card.contains("Cite the data's own authors"), "{card}");
        assert_eq!(parse(&card), Some(tally()));
        let ours = render(&info(), &tally(), &LEROBOT());
        assert!(ours.contains("@software{surgvla") && ours.contains("license: apache-2.0"));
    }

    /// Our data's card: how to load it, what its numbers mean, and the benchmark's paper in
    /// full; another tool's gets the loading snippet only.
    #[test]
    fn a_card_says_how_to_load_the_data_what_it_means_and_whom_to_cite() {
        let format = CardFormat {
            loading: Some("With lerobot:\n\n```python\nprint(1)\n```\n".into()),
            depth: "Stored in metres.",
            ..LEROBOT()
        };
        let card = render(&info(), &tally(), &format);
        for said in [
            "## Loading\n\nWith lerobot:\n\n```python\nprint(1)\n```\n",
            "## Conventions",
            "title = {SurgVLA-Bench: Towards Evaluating Vision-Language-Action Models for Laparoscopic Surgical Robotics}",
            "author = {Sun, Jiashuo and He, Yue and Liu, Wenxuan and Mao, Tao and Wang, Jiazheng and Chen, Xiang and Liu, Min}",
            "eprint = {2606.29247}",
        ] {
            assert!(card.contains(said), "{said}\n{card}");
        }
        let mut foreign = info();
        foreign.generator = String::new();
        foreign.collection = None;
        let card = render(&foreign, &tally(), &format);
        assert!(
            card.contains("## Loading") && !card.contains("## Conventions"),
            "{card}"
        );
        assert!(!card.contains("SurgVLA-Bench: Towards"), "{card}");
    }

    #[test]
    fn a_card_states_its_tally_and_reads_back_the_same() {
        let card = render(&info(), &tally(), &LEROBOT());
        assert!(card.starts_with("---\nlicense: apache-2.0\ntask_categories:\n- robotics\n"));
        assert!(
            card.contains("configs:\n- config_name: default\n  data_files: data/*/*.parquet\n")
        );
        assert!(
            card.contains("3 episodes, 160 frames at 5 frames per second"),
            "{card}"
        );
        assert!(
            card.contains("| `observation.state` | float32 | [7] |"),
            "{card}"
        );
        assert!(card.contains("- `seed`: `3`"), "{card}");
        assert!(card.contains("place it \\| there; put it down"), "{card}");
        assert_eq!(parse(&card), Some(tally()));
        assert_eq!(render(&info(), &tally(), &LEROBOT()), card, "deterministic");
        assert_eq!(parse("# someone else's README\n"), None);
    }

    #[test]
    fn a_card_retallied_is_the_card_of_the_merged_dataset() {
        let mut first = Tally::default();
        first.add("T1-1", 1, 2, 70, &["pick up the gauze".into()]);
        let mut second = Tally::default();
        second.add(
            "T3-1",
            3,
            1,
            90,
            &["place it | there".into(), "put it down".into()],
        );
        let part = render(&info(), &first, &LEROBOT());
        let mut merged = first.clone();
        merged.extend(&second);
        let mut whole_info = info();
        let whole = RecordedShard::Part(crate::export::collection::Shard::default());
        if let Some(collection) = &mut whole_info.collection {
            collection.set_shard(&whole);
        }
        let expected = render(&whole_info, &merged, &LEROBOT());
        assert_eq!(retally(&part, &merged, Some(&whole)), Some(expected));
        assert_eq!(retally("not a card", &merged, Some(&whole)), None);
    }

    #[test]
    fn counts_that_disagree_are_named() {
        assert!(disagreements(&tally(), 3, 160).is_empty());
        let found = disagreements(&tally(), 4, 150);
        assert_eq!(found.len(), 2, "{found:?}");
        assert!(found[0].contains("says 3 episodes, the dataset holds 4"));
    }
}
