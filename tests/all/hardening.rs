//! No dataset folder is ever silently corrupted: resume refuses changed options and damaged
//! files, a folder in use is locked, every finished file has a checksum in the manifest, an
//! interrupted finish resumes with its report, and mistakes in what the user gives exit 2
//! before anything is written.

use crate::util::{surgvla, temp_root, tree};
use std::path::Path;
use surgvla::collect::record::{RecordOptions, episode_seed, record_episode};
use surgvla::collect::run::{CollectOptions, dataset_info};
use surgvla::episode::{Episode, FeatureSet};
use surgvla::error::HasKind as _;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter};
use surgvla::export::{EpisodeSink, ExportError, INCOMPLETE_MARKER, MANIFEST};
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

/// What `collect --tasks T1-1 --episodes-per-task 2` (all else default) writes into.
fn cli_info() -> surgvla::export::DatasetInfo {
    let options = CollectOptions {
        tasks: vec![TaskId::GauzePick],
        episodes_per_task: 2,
        ..CollectOptions::default()
    };
    dataset_info(
        &options,
        FeatureSet::default(),
        &ExpertLibrary::builtin().expect("plans"),
    )
}

const CLI_ARGS: [&str; 5] = ["collect", "--tasks", "T1-1", "--episodes-per-task", "2"];

/// Short gauze-pick episodes.
fn short_episodes(count: u64, steps: u32) -> Vec<Episode> {
    let options = RecordOptions {
        max_steps: Some(steps),
        ..RecordOptions::default()
    };
    let library = ExpertLibrary::builtin().expect("plans");
    let task = TaskId::GauzePick;
    (0..count)
        .map(|i| {
            record_episode(&library, task, episode_seed(0, task, i), i, &options).expect("record")
        })
        .collect()
}

/// Every episode closes its data file, so every episode is a checkpoint.
fn checkpoint_every_episode() -> LeRobotOptions {
    LeRobotOptions {
        data_file_size_mb: 0,
        ..LeRobotOptions::default()
    }
}

/// A dataset "killed" after `episodes` were written (the writer dropped without finishing).
fn interrupted(root: &Path, episodes: &[Episode], options: LeRobotOptions) {
    let mut writer = LeRobotWriter::create(root, &cli_info(), options).expect("create");
    writer.write_batch(episodes).expect("write");
}

fn run(args: &[&str], out: &Path, extra: &[&str]) -> (i32, String, String) {
    let mut all: Vec<&str> = args.to_vec();
    all.extend(["--out", out.to_str().expect("utf-8")]);
    all.extend(extra);
    surgvla(&all)
}

#[test]
fn a_resume_with_options_that_change_the_bytes_is_refused_before_anything_changes() {
    let root = temp_root("resume-options");
    interrupted(&root, &short_episodes(1, 3), LeRobotOptions::default());
    let before = tree(&root);
    for (extra, said) in [
        (vec!["--seed", "4"], "seed was 0, now 4"),
        (vec!["--with-mask"], "features: now also"),
        (vec!["--video", "h264"], "video was null, now"),
        (
            vec!["--lerobot-version", "2.1"],
            "lerobot_version was \"3.0\", now \"2.1\"",
        ),
        (vec!["--gripper-encoding", "pulse"], "gripper_encoding was"),
        (vec!["--shard", "1/2"], "shard was \"0/1\", now \"1/2\""),
        (vec!["--data-file-mb", "5"], "data_file_mb was 100, now 5"),
    ] {
        let mut resume = extra.clone();
        resume.push("--resume");
        let (code, _, stderr) = run(&CLI_ARGS, &root, &resume);
        assert_eq!(code, 2, "{extra:?}: {stderr}");
        assert!(stderr.contains(said), "{extra:?}: {stderr}");
        assert_eq!(tree(&root), before, "{extra:?} changed the folder");
    }
    let (code, _, stderr) = run(
        &["collect", "--tasks", "T1-1", "--episodes-per-task", "5"],
        &root,
        &["--resume"],
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("episodes_per_task was 2, now 5"),
        "{stderr}"
    );
    // Options that do not change the bytes may differ.
    let (code, _, stderr) = run(&CLI_ARGS, &root, &["--resume", "--threads", "1"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(!root.join(INCOMPLETE_MARKER).exists());
}

#[test]
fn a_folder_in_use_is_locked_and_left_as_it_was() {
    let root = temp_root("locked");
    let mut writer =
        LeRobotWriter::create(&root, &cli_info(), LeRobotOptions::default()).expect("create");
    writer.write_batch(&short_episodes(1, 2)).expect("write");
    let before = tree(&root);
    let holder = format!("surgvla process {}", std::process::id());
    for extra in [&[][..], &["--resume"][..]] {
        let (code, _, stderr) = run(&CLI_ARGS, &root, extra);
        assert_eq!(code, 2, "{extra:?}: {stderr}");
        assert!(
            stderr.contains("is being written by another run") && stderr.contains(&holder),
            "{extra:?}: {stderr}"
        );
        assert_eq!(tree(&root), before, "{extra:?} changed the folder");
    }
    writer.finish().expect("finish");
    assert!(!root.join(INCOMPLETE_MARKER).exists());
}

#[test]
fn two_runs_started_together_into_one_new_folder_leave_one_complete_dataset() {
    let root = temp_root("race");
    let spawn = |shard: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
            .args(CLI_ARGS)
            .args(["--shard", shard, "--out", root.to_str().expect("utf-8")])
            .output()
            .expect("spawn")
    };
    let (a, b) = std::thread::scope(|s| {
        let a = s.spawn(|| spawn("0/2"));
        let b = s.spawn(|| spawn("1/2"));
        (a.join().expect("a"), b.join().expect("b"))
    });
    let mut codes = [a.status.code(), b.status.code()];
    codes.sort();
    assert_eq!(codes, [Some(0), Some(2)], "{a:?} {b:?}");
    let loser = if a.status.code() == Some(2) { &a } else { &b };
    let said = String::from_utf8_lossy(&loser.stderr);
    assert!(
        said.contains("being written by another run") || said.contains("already holds"),
        "{said}"
    );
    assert!(root.join("meta/info.json").exists());
    assert!(!root.join(INCOMPLETE_MARKER).exists());
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("meta/info.json")).expect("info"))
            .expect("json");
    assert_eq!(info["total_episodes"], 1, "one shard's episode, not a mix");
}

#[test]
fn resume_refuses_a_checkpointed_file_that_is_missing_truncated_or_changed() {
    let episodes = short_episodes(3, 3);
    type Damage = fn(&Path);
    let damages: [(&str, Damage, &str); 3] = [
        (
            "missing",
            |p| std::fs::remove_file(p).expect("remove"),
            "is missing",
        ),
        (
            "truncated",
            |p| {
                let f = std::fs::OpenOptions::new()
                    .write(true)
                    .open(p)
                    .expect("open");
                f.set_len(100).expect("truncate");
            },
            "is 100 bytes",
        ),
        (
            "flipped",
            |p| {
                let mut bytes = std::fs::read(p).expect("read");
                let middle = bytes.len() / 2;
                bytes[middle] ^= 0x10;
                std::fs::write(p, bytes).expect("write");
            },
            "CRC-32C",
        ),
    ];
    for (name, damage, said) in damages {
        let root = temp_root(name);
        interrupted(&root, &episodes, checkpoint_every_episode());
        let victim = root.join("data/chunk-000/file-001.parquet");
        damage(&victim);
        let before = tree(&root);
        match LeRobotWriter::resume(&root, &cli_info(), checkpoint_every_episode()) {
            Err(error @ ExportError::Damaged { .. }) => {
                let message = error.to_string();
                assert!(message.contains(&victim.display().to_string()), "{message}");
                assert!(message.contains(said), "{name}: {message}");
                assert_eq!(error.kind().exit_code(), 1);
            }
            Err(other) => panic!("{name}: expected Damaged, got {other}"),
            Ok(_) => panic!("{name}: a damaged dataset was resumed"),
        }
        assert_eq!(
            tree(&root),
            before,
            "{name}: a refused resume changed the folder"
        );
    }
    // Intact, it resumes after the last checkpoint.
    let root = temp_root("intact");
    interrupted(&root, &episodes, checkpoint_every_episode());
    let writer =
        LeRobotWriter::resume(&root, &cli_info(), checkpoint_every_episode()).expect("resume");
    assert_eq!(writer.next_episode_index(), 3);
}

#[test]
fn a_finished_dataset_lists_every_file_with_its_size_and_checksum() {
    let root = temp_root("manifest");
    let mut writer =
        LeRobotWriter::create(&root, &cli_info(), checkpoint_every_episode()).expect("create");
    writer.write_batch(&short_episodes(2, 3)).expect("write");
    writer.finish().expect("finish");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join(MANIFEST)).expect("manifest"))
            .expect("json");
    assert_eq!(manifest["checksum"], "crc32c");
    let mut files = tree(&root);
    files.remove(MANIFEST);
    let listed: Vec<&str> = manifest["files"]
        .as_array()
        .expect("files")
        .iter()
        .map(|f| f["path"].as_str().expect("path"))
        .collect();
    assert_eq!(listed, files.keys().map(String::as_str).collect::<Vec<_>>());
    for entry in manifest["files"].as_array().expect("files") {
        let bytes = &files[entry["path"].as_str().expect("path")];
        assert_eq!(entry["bytes"], bytes.len() as u64);
        assert_eq!(entry["crc32c"], format!("{:08x}", crc32c::crc32c(bytes)));
    }
    assert!(listed.contains(&"data/chunk-000/file-001.parquet"));
    assert!(listed.contains(&"meta/info.json"));
}

#[test]
fn an_interrupted_finish_resumes_to_the_same_bytes_with_its_report() {
    let episodes = short_episodes(3, 3);
    let reference = temp_root("finish-reference");
    let mut writer =
        LeRobotWriter::create(&reference, &cli_info(), checkpoint_every_episode()).expect("create");
    writer.write_batch(&episodes).expect("write");
    writer.finish().expect("finish");

    let root = temp_root("finish-interrupted");
    let mut writer =
        LeRobotWriter::create(&root, &cli_info(), checkpoint_every_episode()).expect("create");
    writer.write_batch(&episodes).expect("write");
    // The report cannot be written (a kill or a full disk at that moment).
    let mut failing =
        |_: &surgvla::export::Summary| -> Result<Vec<(String, Vec<u8>)>, ExportError> {
            Err(ExportError::Internal(
                "killed while writing the report".into(),
            ))
        };
    assert!(writer.finish_with(Some(&mut failing)).is_err());
    drop(writer);
    assert!(
        root.join(INCOMPLETE_MARKER).exists(),
        "a finish without its report must stay resumable"
    );
    let mut writer = crate::util::unless_briefly_locked(|| {
        LeRobotWriter::resume(&root, &cli_info(), checkpoint_every_episode())
    })
    .expect("resume");
    assert_eq!(writer.next_episode_index(), 3, "nothing is written again");
    let mut report = |s: &surgvla::export::Summary| -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        Ok(vec![(
            "collect_report.json".into(),
            format!("{}\n", s.episodes).into_bytes(),
        )])
    };
    let summary = writer.finish_with(Some(&mut report)).expect("finish");
    assert_eq!(summary.episodes, 3);
    assert!(!root.join(INCOMPLETE_MARKER).exists());
    let mut files = tree(&root);
    assert_eq!(files.remove("collect_report.json").expect("report"), b"3\n");
    assert_eq!(files, tree(&reference));
}

/// A plans folder holding `files` (name, text).
fn plans(files: &[(&str, String)]) -> crate::util::TempRoot {
    let folder = temp_root("plans");
    std::fs::create_dir_all(&*folder).expect("folder");
    for (name, text) in files {
        std::fs::write(folder.join(name), text).expect("plan");
    }
    folder
}

fn gauze_plan() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scripted_policies/gauze_pick.toml"
    ))
    .expect("plan")
}

#[test]
fn mistakes_in_what_the_user_gives_exit_2_before_anything_is_written() {
    let out = temp_root("mistakes-hardening");
    let bad_value = |from: &str, to: &str| gauze_plan().replacen(from, to, 1);
    let cases: Vec<(Vec<String>, Option<crate::util::TempRoot>, Vec<&str>)> = vec![
        (
            vec!["--tasks".into(), "T1-1,gauze_pick".into()],
            None,
            vec!["T1-1 (gauze_pick) is listed twice"],
        ),
        (
            vec!["--threads".into(), "100000".into()],
            None,
            vec!["100000", "at most"],
        ),
        (
            vec![
                "--tasks".into(),
                "T1-1".into(),
                "--episodes-per-task".into(),
                "1".into(),
                "--shard".into(),
                "0/2".into(),
            ],
            None,
            vec!["shard 0/2 would hold no episode", "1 in all"],
        ),
        (
            vec![],
            Some(plans(&[(
                "a.toml",
                bad_value("offset_m = [0.0, 0.0, 0.02]", "offset_m = [0.0, nan, 0.02]"),
            )])),
            vec!["a.toml", "waypoint 0 ('approach') offset_m[1] = NaN"],
        ),
        (
            vec![],
            Some(plans(&[(
                "a.toml",
                bad_value(
                    "offset_m = [0.0, 0.0, 0.02]",
                    "offset_m = [0.0, 0.0, 1e300]",
                ),
            )])),
            vec!["a.toml", "offset_m[2] = 1e300"],
        ),
        (
            vec![],
            Some(plans(&[(
                "a.toml",
                bad_value("yaw_jitter_deg = 8.0", "yaw_jitter_deg = inf"),
            )])),
            vec!["a.toml", "yaw_jitter_deg = inf"],
        ),
        (
            vec![],
            Some(plans(&[(
                "a.toml",
                format!("position_tolerance_m = -inf\n{}", gauze_plan()),
            )])),
            vec!["a.toml", "position_tolerance_m = -inf"],
        ),
        (
            vec![],
            Some(plans(&[(
                "a.toml",
                bad_value("frame = \"pick\"", "frame = \"place\""),
            )])),
            vec![
                "a.toml",
                "uses frame 'place', which this task does not have",
            ],
        ),
        (
            vec![],
            Some(plans(&[("a.toml", gauze_plan()), ("b.toml", gauze_plan())])),
            vec!["b.toml", "a.toml", "a second plan for gauze_pick"],
        ),
    ];
    for (args, folder, said) in cases {
        let mut all: Vec<&str> = vec!["collect", "--out", out.to_str().expect("utf-8")];
        all.extend(args.iter().map(String::as_str));
        let folder_arg;
        if let Some(folder) = &folder {
            folder_arg = folder.to_str().expect("utf-8").to_string();
            all.extend(["--policies", folder_arg.as_str()]);
        }
        let (code, _, stderr) = surgvla(&all);
        assert_eq!(code, 2, "{all:?}: {stderr}");
        for needle in said {
            assert!(stderr.contains(needle), "{all:?}: {stderr}");
        }
        assert!(!out.exists(), "{all:?} wrote something");
    }
}

#[test]
fn a_folder_left_with_only_the_marker_says_to_resume() {
    let root = temp_root("marker-only");
    interrupted(&root, &[], LeRobotOptions::default());
    let (code, _, stderr) = run(&CLI_ARGS, &root, &[]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("add --resume"), "{stderr}");
}

#[test]
fn a_full_stdout_is_an_error_without_a_resume_hint() {
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .expect("/dev/full");
    for args in [&["sim"][..], &["schema"][..]] {
        let output = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
            .args(args)
            .stdout(full.try_clone().expect("clone"))
            .output()
            .expect("run");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains("No space left"), "{stderr}");
        assert!(!stderr.contains("--resume"), "{args:?}: {stderr}");
    }
}

#[test]
fn the_writers_state_does_not_grow_with_the_number_of_episodes() {
    // The state a checkpoint records is what the writer keeps in memory between episodes; the
    // rows of the episodes table go to a journal on disk.
    let state_after = |count: u64| {
        let root = temp_root("state");
        interrupted(&root, &short_episodes(count, 2), checkpoint_every_episode());
        let marker: serde_json::Value =
            serde_json::from_slice(&std::fs::read(root.join(INCOMPLETE_MARKER)).expect("marker"))
                .expect("json");
        let mut state = marker["checkpoint"]["state"].clone();
        let stats = state
            .as_object_mut()
            .expect("state")
            .remove("stats")
            .expect("stats");
        (state, stats.to_string().len())
    };
    let (two, stats_two) = state_after(2);
    let (eight, stats_eight) = state_after(8);
    assert_eq!(eight["episodes"], 8);
    let size = |v: &serde_json::Value| v.to_string().len();
    assert!(
        size(&eight) <= size(&two) + 16,
        "state grew from {} to {} bytes: {eight}",
        size(&two),
        size(&eight)
    );
    // Statistics keep bounded reservoirs: they grow with frames only until the reservoirs fill.
    assert!(stats_eight < 2 * stats_two, "{stats_two} -> {stats_eight}");
}
