//! Whole collections: thread-count independence, shards, the report, and resuming a killed run.

use crate::util::{TempRoot, info, surgvla, temp_root, tree};
use std::path::Path;
use std::sync::{Arc, Mutex};
use surgvla::collect::run::{CollectOptions, Shard, Silent, collect};
use surgvla::episode::Episode;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter};
use surgvla::export::{EpisodeSink, ExportError, Summary};
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

fn small(tasks: &[TaskId], episodes_per_task: u64, threads: usize) -> CollectOptions {
    CollectOptions {
        tasks: tasks.to_vec(),
        episodes_per_task,
        seed: 3,
        threads,
        ..CollectOptions::default()
    }
}

#[test]
fn one_and_two_threads_write_identical_datasets() {
    let library = ExpertLibrary::builtin().unwrap();
    let tasks = [TaskId::NeedlePick, TaskId::Hemostasis];
    let mut trees = Vec::new();
    let mut reports = Vec::new();
    for threads in [1, 2] {
        let root = temp_root("threads");
        let mut writer =
            LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).unwrap();
        let report = collect(
            &small(&tasks, 2, threads),
            &library,
            &mut writer,
            &mut Silent,
        )
        .unwrap();
        let mut files = tree(&root);
        // The report's timings differ between runs; its counts are compared below.
        assert!(files.remove("collect_report.json").is_some());
        trees.push(files);
        reports.push(report);
    }
    assert_eq!(
        trees[0].keys().collect::<Vec<_>>(),
        trees[1].keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &trees[0] {
        assert!(
            trees[1][name] == *bytes,
            "{name} differs between 1 and 2 threads"
        );
    }
    let (a, b) = (&reports[0], &reports[1]);
    assert_eq!(
        (a.episodes, a.frames, &a.tasks, &a.failures),
        (b.episodes, b.frames, &b.tasks, &b.failures)
    );
    assert_eq!(a.episodes, 4);
    assert_eq!(a.dataset.episodes, 4);
    assert!(a.tasks.iter().all(|t| t.episodes == 2 && t.attempts >= 2));
    // Every stage's time is measured (LeRobot encodes and computes statistics on the workers,
    // the writer builds tables and files, the finish writes the metadata); none is counted
    // twice, so together they fit in the threads' time.
    for report in &reports {
        let t = &report.timing;
        let stages = [
            t.physics_cpu_secs,
            t.render_cpu_secs,
            t.encode_cpu_secs,
            t.stats_cpu_secs,
            t.write_cpu_secs,
            t.finish_cpu_secs,
        ];
        assert!(stages.iter().all(|s| *s > 0.0), "{t:?}");
        let busy = (report.threads + 1) as f64 * t.wall_secs;
        assert!(stages.iter().sum::<f64>() <= busy, "{t:?}");
    }
}

/// What the memory sink keeps of an episode: index, seed, instruction, length, actions.
type Kept = (u64, u64, String, usize, Vec<[f32; 7]>);

/// Records what reaches it.
#[derive(Clone, Default)]
struct Memory(Arc<Mutex<Vec<Kept>>>);

impl EpisodeSink for Memory {
    fn write_batch(&mut self, episodes: &[Episode]) -> Result<(), ExportError> {
        for episode in episodes {
            let actions = episode.steps.iter().map(|s| s.action).collect();
            self.0.lock().unwrap().push((
                episode.meta.index,
                episode.meta.seed,
                episode.meta.instruction.clone(),
                episode.steps.len(),
                actions,
            ));
        }
        Ok(())
    }

    fn next_episode_index(&self) -> u64 {
        0
    }

    fn finish_with(
        &mut self,
        sidecar: Option<surgvla::export::Sidecar<'_>>,
    ) -> Result<Summary, ExportError> {
        if let Some(make) = sidecar {
            make(&Summary::default())?;
        }
        Ok(Summary::default())
    }
}

#[test]
fn shards_in_order_hold_exactly_the_unsharded_episodes() {
    let library = ExpertLibrary::builtin().unwrap();
    let tasks = [
        TaskId::GauzePick,
        TaskId::Electrocoagulation,
        TaskId::VesselClipping,
    ];
    let run = |shard: Shard| {
        let mut memory = Memory::default();
        let options = CollectOptions {
            shard,
            ..small(&tasks, 2, 2)
        };
        let report = collect(&options, &library, &mut memory, &mut Silent).unwrap();
        let episodes = memory.0.lock().unwrap().clone();
        (episodes, report)
    };
    let (full, _) = run(Shard::default());
    assert_eq!(full.len(), 6);
    let mut joined = Vec::new();
    let mut ranges = Vec::new();
    for index in 0..3 {
        let (part, report) = run(Shard { index, count: 3 });
        // Each shard numbers its own episodes from 0.
        assert!(part.iter().enumerate().all(|(i, e)| e.0 == i as u64));
        ranges.push(report.slot_range);
        joined.extend(part.into_iter().map(|e| (e.1, e.2, e.3, e.4)));
    }
    assert_eq!(ranges, [[0, 2], [2, 4], [4, 6]]);
    let full: Vec<_> = full.into_iter().map(|e| (e.1, e.2, e.3, e.4)).collect();
    assert_eq!(joined, full);
}

#[test]
fn a_killed_collect_resumes_to_the_uninterrupted_dataset() {
    let args = |out: &Path| -> Vec<String> {
        [
            "collect",
            "--tasks",
            "T1-1,T3-1",
            "--episodes-per-task",
            "4",
            "--seed",
            "8",
            "--threads",
            "1",
            "--data-file-mb",
            "1",
            "--out",
        ]
        .iter()
        .map(|s| s.to_string())
        .chain([out.display().to_string()])
        .collect()
    };
    let reference = temp_root("uninterrupted");
    let (code, stdout, stderr) = surgvla(
        &args(&reference)
            .iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>(),
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("T3-1") && stdout.contains("frames/s"),
        "{stdout}"
    );

    // Kill a second run once it has checkpointed at least one data file.
    let killed = temp_root("killed");
    let killed_args = args(&killed);
    let killed_args: Vec<&str> = killed_args.iter().map(String::as_str).collect();
    crate::util::kill_after_checkpoint(&killed_args, &killed);
    assert!(
        !killed.join("meta/info.json").exists(),
        "a killed run must not look complete"
    );

    let mut resume = args(&killed);
    resume.push("--resume".into());
    let (code, _, stderr) = surgvla(&resume.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("resuming"), "{stderr}");

    let (mut a, mut b) = (tree(&reference), tree(&killed));
    let report_a: serde_json::Value =
        serde_json::from_slice(&a.remove("collect_report.json").unwrap()).unwrap();
    let report_b: serde_json::Value =
        serde_json::from_slice(&b.remove("collect_report.json").unwrap()).unwrap();
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs after resume");
    }
    for key in ["episodes", "frames", "tasks", "failures", "dataset"] {
        assert_eq!(report_a[key], report_b[key], "report {key}");
    }
    assert!(report_b["resumed_at_episode"].as_u64().unwrap() > 0);
    assert_eq!(report_a["episodes"], 8);
    assert!(
        report_a["tasks"][1]["expert_success_rate"]
            .as_f64()
            .unwrap()
            > 0.0
    );
}

#[test]
fn collect_mistakes_exit_2_with_the_reason() {
    let out = temp_root("mistakes");
    let out = out.display().to_string();
    for (args, needle) in [
        (
            vec!["collect", "--shard", "3/3", "--out", &out],
            "shard '3/3'",
        ),
        (
            vec!["collect", "--tasks", "T9-9", "--out", &out],
            "unknown task 'T9-9'",
        ),
        (
            vec!["collect", "--policies", "/nonexistent/plans", "--out", &out],
            "/nonexistent/plans",
        ),
        (
            vec!["collect", "--spawn-scale", "9", "--out", &out],
            "--spawn-scale",
        ),
        (vec!["collect", "--format", "hdf5", "--out", &out], "hdf5"),
    ] {
        let (code, _, stderr) = surgvla(&args);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
        assert!(!Path::new(&out).exists(), "{args:?} created the output");
    }
}

/// The built-in plans with T3-2's release 25 mm beside the target: the gauze lands off target.
fn broken_hemostasis_plans() -> (TempRoot, ExpertLibrary) {
    let folder = temp_root("plans");
    std::fs::create_dir_all(&folder).unwrap();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scripted_policies/hemostasis.toml"),
    )
    .unwrap()
    .replace(
        "frame = \"place\"\noffset_m = [0.0, 0.0, 0.005]",
        "frame = \"place\"\noffset_m = [0.025, 0.0, 0.005]",
    );
    std::fs::write(folder.join("hemostasis.toml"), text).unwrap();
    let library = ExpertLibrary::with_folder(&folder).unwrap();
    (folder, library)
}

#[test]
fn measuring_experts_counts_failures_and_collect_stops_on_an_exhausted_slot() {
    let (_plans_folder, library) = broken_hemostasis_plans();
    let options = CollectOptions {
        max_attempts: 2,
        ..small(&[TaskId::GauzePick, TaskId::Hemostasis], 4, 2)
    };
    let report = surgvla::collect::run::measure_experts(&options, &library, &mut Silent).unwrap();
    assert_eq!(report.tasks[0].expert_success_rate, 1.0);
    let hemostasis = &report.tasks[1];
    assert_eq!(hemostasis.expert_success_rate, 0.0, "{hemostasis:?}");
    assert_eq!((hemostasis.episodes, hemostasis.attempts), (0, 8));
    assert!(
        report
            .failures
            .iter()
            .all(|f| f.stage == surgvla::collect::slot::FailureStage::Expert
                && f.slot.task == TaskId::Hemostasis)
    );
    // Let go 25 mm aside: off the spot, or (where the spleen's flank falls away) a drop.
    let reason = &report.failures[0].reason;
    assert!(
        reason.contains("not under the gauze") || reason.contains("gauze dropped"),
        "{reason}"
    );

    let root = temp_root("exhausted");
    let mut writer = LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).unwrap();
    let error = collect(&options, &library, &mut writer, &mut Silent)
        .expect_err("a slot with no verified episode stops the collection");
    assert!(error.to_string().contains("hemostasis episode"), "{error}");
    assert!(!root.join("meta/info.json").exists());
}

#[test]
fn the_experts_command_prints_rates_and_reproducible_failures() {
    let (code, stdout, stderr) = surgvla(&[
        "experts",
        "--tasks",
        "T1-1,T2-3",
        "--episodes-per-task",
        "3",
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("T2-3") && stdout.contains("100.0%"),
        "{stdout}"
    );
    let (folder, _) = broken_hemostasis_plans();
    let folder_arg = folder.display().to_string();
    let (code, stdout, stderr) = surgvla(&[
        "experts",
        "--tasks",
        "T3-2",
        "--episodes-per-task",
        "4",
        "--max-attempts",
        "2",
        "--policies",
        &folder_arg,
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        (stdout.contains("(expert): 'bleeding_target' not under the gauze")
            || stdout.contains("(expert): gauze dropped"))
            && stdout.contains("[seed "),
        "{stdout}"
    );
}

/// `--tasks` takes levels mixed with tasks, and `--per-level` writes one complete dataset per
/// level, each the bytes of `collect --tasks L<N>` into it (the report's timings aside).
#[test]
fn per_level_datasets_equal_their_levels_collected_alone() {
    let root = temp_root("collect-per-level");
    let text = |p: &Path| p.to_str().expect("utf-8").to_string();
    let (out, alone) = (root.join("levels"), root.join("level1-alone"));
    let run = |args: &[&str]| {
        let (code, stdout, err) = surgvla(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        stdout
    };
    let stdout = run(&[
        "collect",
        "--per-level",
        "--tasks",
        "L1,T3-1",
        "--episodes-per-task",
        "1",
        "--out",
        &text(&out),
    ]);
    assert!(stdout.contains("wrote 3 episodes") && stdout.contains("wrote 1 episode,"));
    run(&[
        "collect",
        "--tasks",
        "level1",
        "--episodes-per-task",
        "1",
        "--out",
        &text(&alone),
    ]);
    let files = |p: &Path| {
        let mut files = tree(p);
        files.remove("collect_report.json");
        files
    };
    let names: Vec<String> = std::fs::read_dir(&out)
        .expect("out")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    assert_eq!(names, ["level1", "level3"]);
    assert!(
        files(&out.join("level1")) == files(&alone),
        "level1 differs"
    );
    // A finished level is passed over on --resume.
    let stdout = run(&[
        "collect",
        "--per-level",
        "--tasks",
        "L1,T3-1",
        "--episodes-per-task",
        "1",
        "--resume",
        "--out",
        &text(&out),
    ]);
    assert!(stdout.contains("level1 is complete already"), "{stdout}");
}
