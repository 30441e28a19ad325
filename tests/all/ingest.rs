//! `surgvla ingest` end to end on recordings the real writers made (tests/fixtures/ingest): the
//! datasets, their reports and cards, the same bytes twice, a resume after an interruption,
//! shards, and what bad input gets.

use crate::util::{surgvla, temp_root, tree};
use std::path::{Path, PathBuf};
use surgvla::episode::FeatureValue;
use surgvla::export::{EpisodeSource, INCOMPLETE_MARKER};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/ingest")
        .join(name)
}

/// `surgvla ingest INPUTS --camera CAMERA --out OUT EXTRA...`.
fn ingest_with(
    inputs: &[&Path],
    camera: &str,
    out: &Path,
    extra: &[&str],
) -> (i32, String, String) {
    let mut args = vec!["ingest"];
    args.extend(inputs.iter().map(|p| p.to_str().expect("utf-8")));
    args.extend(["--camera", camera, "--out", out.to_str().expect("utf-8")]);
    args.extend_from_slice(extra);
    surgvla(&args)
}

/// Both fixtures, the left camera.
fn ingest(out: &Path, extra: &[&str]) -> (i32, String, String) {
    let (bag, mcap) = (fixture("ros1_raw_lz4.bag"), fixture("single_png.mcap"));
    ingest_with(&[&bag, &mcap], "left=/camera/left/image", out, extra)
}

#[test]
fn ingest_writes_a_dataset_with_a_report_per_input_and_the_same_bytes_twice() {
    let root = temp_root("ingest-twice");
    let (first, second) = (root.join("a"), root.join("b"));
    let (code, stdout, stderr) = ingest(&first, &["--verify"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("ingested 4 episodes") && stdout.contains("verified"),
        "{stdout}"
    );
    assert!(stderr.contains("ros1_raw_lz4.bag: 2 episodes"), "{stderr}");
    let files = tree(&first);
    for report in [
        "meta/sync/ros1_raw_lz4.bag.json",
        "meta/sync/single_png.mcap.json",
    ] {
        let json: serde_json::Value =
            serde_json::from_slice(&files[report]).expect("a JSON report");
        let camera = &json["streams"][4];
        assert_eq!(camera["topic"], "/camera/left/image");
        assert_eq!(
            camera["gaps"].as_array().map(Vec::len),
            Some(1),
            "the dropout"
        );
        assert_eq!(camera["out_of_order"], 1);
        assert!(json["dropped_frames"].as_u64() > Some(0));
    }
    let card = String::from_utf8_lossy(&files["README.md"]).into_owned();
    assert!(card.contains("Synchronisation") && card.contains("`ros1_raw_lz4.bag` | 2 |"));
    assert!(
        !card.contains("- surgvla\n"),
        "not tagged as surgvla's simulated data"
    );
    let mut source = surgvla::export::open_source(&first).expect("read back");
    assert_eq!(source.len(), 4);
    let episode = source.next().expect("an episode").expect("read");
    assert_eq!(episode.meta.instruction, "grasp the needle");
    let [
        FeatureValue::Image(_),
        FeatureValue::Float32(state),
        FeatureValue::Float32(action),
    ] = &episode.steps[0].other[..]
    else {
        panic!("the camera, the state and the action");
    };
    assert_eq!((state.len(), action.len()), (8, 8));
    let (code, _, stderr) = ingest(&second, &[]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(
        files,
        tree(&second),
        "same recordings and options, same bytes"
    );
    let (code, _, stderr) = surgvla(&["validate", first.to_str().expect("utf-8")]);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn every_format_that_holds_the_robots_features_takes_them() {
    let root = temp_root("ingest-formats");
    for extra in [
        &["--to", "rlds"][..],
        &["--lerobot-version", "2.1"],
        &["--video", "h264"],
    ] {
        let out = root.join(extra.join("-"));
        let mut args = extra.to_vec();
        args.push("--verify");
        let (code, stdout, stderr) = ingest(&out, &args);
        assert_eq!(code, 0, "{extra:?}: {stderr}");
        assert!(stdout.contains("verified"), "{extra:?}: {stdout}");
    }
    assert!(root.join("--to-rlds/sync/ros1_raw_lz4.bag.json").is_file());
    // Formats of surgvla's own features refuse, before anything is written.
    let out = root.join("zarr");
    let (code, _, stderr) = ingest(&out, &["--to", "zarr"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("LeRobot, RLDS or MCAP keep them"),
        "{stderr}"
    );
    assert!(!out.exists());
}

#[test]
fn an_interrupted_ingest_resumes_to_the_same_bytes() {
    use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter};
    use surgvla::ingest::dvrk::DvrkPreset;
    use surgvla::ingest::source::{IngestOptions, IngestSource, Parting};
    let root = temp_root("ingest-resume");
    let inputs = [fixture("ros1_raw_lz4.bag"), fixture("single_png.mcap")];
    let options = IngestOptions {
        preset: DvrkPreset::new(
            &["PSM1".into()],
            &[("left".into(), "/camera/left/image".into())],
        ),
        clock: surgvla::ingest::stamps::Clock::Header,
        sync: surgvla::ingest::sync::SyncOptions::at(30),
        task: None,
        offsets_ns: Vec::new(),
        instruction_text: true,
        splits: vec![("train".into(), 0..3), ("recovery".into(), 3..4)],
        scratch: None,
        // Episodes written in parts of 8 frames.
        parting: Parting {
            batch_frames: 8,
            part_bytes: 1,
        },
    };
    let every_episode = LeRobotOptions {
        data_file_size_mb: 0,
        ..LeRobotOptions::default()
    };
    let run = |out: &Path, resume: bool| {
        let mut source = IngestSource::open(&inputs, options.clone()).expect("open");
        let mut sink = crate::util::unless_briefly_locked(|| {
            LeRobotWriter::boxed(out, source.info(), every_episode.clone(), resume)
        })
        .expect("sink");
        surgvla::export::convert::convert(&mut source, sink.as_mut(), 1, &mut |_| {})
            .expect("convert");
    };
    let whole = root.join("whole");
    run(&whole, false);
    // Killed in the fourth episode (the second input's first), after its first part.
    let resumed = root.join("resumed");
    {
        use surgvla::export::{EpisodeSink, EpisodeSource};
        let mut source = IngestSource::open(&inputs, options.clone()).expect("open");
        let mut writer =
            LeRobotWriter::create(&resumed, source.info(), every_episode.clone()).expect("create");
        let mut ended = 0;
        while ended < 3 {
            let part = source.next_part().expect("a part").expect("read");
            ended += usize::from(part.last);
            writer.write_part(&part).expect("write");
        }
        let part = source.next_part().expect("a part").expect("read");
        assert!(!part.last, "the fourth episode comes in parts");
        writer.write_part(&part).expect("write");
    }
    assert!(resumed.join(INCOMPLETE_MARKER).exists());
    run(&resumed, true);
    assert_eq!(tree(&whole), tree(&resumed));
}

#[test]
fn shards_take_contiguous_inputs() {
    let root = temp_root("ingest-shards");
    let (code, stdout, stderr) = ingest(&root.join("0"), &["--shard", "0/2"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("ingested 2 episodes") && stdout.contains("from 1 recording "));
    assert!(root.join("0/meta/sync/ros1_raw_lz4.bag.json").is_file());
    assert!(!root.join("0/meta/sync/single_png.mcap.json").exists());
    // 2 inputs over 3 shards: the first holds none.
    let (code, _, stderr) = ingest(&root.join("3"), &["--shard", "0/3"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("would hold no input"), "{stderr}");
}

#[test]
fn bad_input_is_named_and_leaves_no_dataset_that_looks_complete() {
    let root = temp_root("ingest-bad");
    std::fs::create_dir_all(&root).expect("root");
    // A topic the recording lacks: the data is not what was asked (exit 1).
    let out = root.join("missing");
    let bag = fixture("ros1_raw_lz4.bag");
    let (code, _, stderr) = ingest_with(&[&bag], "left=/camera/right/image", &out, &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("ros1_raw_lz4.bag has no message on /camera/right/image"),
        "{stderr}"
    );
    assert!(!out.exists());
    // A bag cut short, and bytes that are no recording.
    let bytes = std::fs::read(&bag).expect("read");
    for (name, content) in [
        ("cut.bag", &bytes[..bytes.len() / 2]),
        ("noise.bag", &b"hello"[..]),
    ] {
        let input = root.join(name);
        std::fs::write(&input, content).expect("write");
        let out = root.join(format!("{name}-out"));
        let (code, _, stderr) = ingest_with(&[&input], "left=/camera/left/image", &out, &[]);
        assert_eq!(code, 1, "{name}: {stderr}");
        assert!(
            stderr.contains(name) && stderr.contains("byte"),
            "{name}: {stderr}"
        );
        assert!(!out.exists() || out.join(INCOMPLETE_MARKER).exists());
    }
    // What the user gave: exit 2.
    let out = root.join("usage");
    let left = "left=/camera/left/image";
    let nowhere = Path::new("/no/such.bag");
    for (input, camera, extra) in [
        (bag.as_path(), left, &["--time-offset", "/nope=5"][..]),
        (&bag, "left", &[]),
        (&bag, "a/b=/camera/left/image", &[]),
        (nowhere, left, &[]),
        (&bag, left, &["--tolerance-ms", "0"]),
    ] {
        let (code, _, stderr) = ingest_with(&[input], camera, &out, extra);
        let args = (input, camera, extra);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(!out.exists());
    }
}

#[test]
fn a_time_offset_and_the_receive_clock_move_the_grid() {
    let root = temp_root("ingest-clock");
    let report = |out: &Path| -> serde_json::Value {
        serde_json::from_slice(
            &std::fs::read(out.join("meta/sync/ros1_raw_lz4.bag.json")).expect("report"),
        )
        .expect("json")
    };
    let bag = fixture("ros1_raw_lz4.bag");
    let run = |name: &str, extra: &[&str]| {
        let out = root.join(name);
        let mut args = vec!["--task", "suture"];
        args.extend_from_slice(extra);
        let (code, _, stderr) = ingest_with(&[&bag], "left=/camera/left/image", &out, &args);
        assert_eq!(code, 0, "{stderr}");
        report(&out)
    };
    let header = run("header", &[]);
    let shifted = run("shifted", &["--time-offset", "/camera/left/image=100"]);
    let receive = run("receive", &["--clock", "receive"]);
    let start = |r: &serde_json::Value| r["grid"][0].as_i64().expect("a grid");
    assert_ne!(start(&header), start(&receive));
    assert_eq!(
        start(&shifted),
        start(&header) + 100_000_000,
        "the camera starts last"
    );
    let mut source = surgvla::export::open_source(&root.join("header")).expect("read");
    let episode = source.next().expect("an episode").expect("read");
    assert_eq!(
        episode.meta.instruction, "suture",
        "--task wins over /instruction"
    );
}

#[test]
fn the_open_h_profile_writes_lerobot_2_1_video_with_its_readme_splits_and_instructions() {
    let root = temp_root("ingest-open-h");
    let out = root.join("suturing");
    let splits = ["--split", "train=0:3", "--split", "recovery=3:4"];
    let mut extra = vec!["--profile", "open-h", "--verify"];
    extra.extend(splits);
    let (code, stdout, stderr) = ingest(&out, &extra);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("verified"), "{stdout}");
    let files = tree(&out);
    let info: serde_json::Value =
        serde_json::from_slice(&files["meta/info.json"]).expect("info.json");
    assert_eq!(info["codebase_version"], "v2.1");
    assert_eq!(
        info["splits"],
        serde_json::json!({"train": "0:3", "recovery": "3:4"})
    );
    assert_eq!(
        info["features"]["observation.images.left"]["dtype"],
        "video"
    );
    assert_eq!(
        info["features"]["observation.images.left"]["info"]["video.codec"],
        "h264"
    );
    assert_eq!(info["features"]["instruction.text"]["dtype"], "string");
    assert!(
        files
            .keys()
            .any(|f| f.starts_with("videos/") && f.ends_with(".mp4"))
    );
    // Text has no statistics.
    let stats: serde_json::Value =
        serde_json::from_slice(&files["meta/stats.json"]).expect("stats");
    assert!(stats.get("instruction.text").is_none() && stats.get("action").is_some());
    let readme = String::from_utf8(files["meta/README.md"].clone()).expect("utf-8");
    for wanted in [
        "# suturing - README",
        "| **Total Trajectories** | `4` |",
        "## ⏱️ Data Synchronization Approach",
        "| `ros1_raw_lz4.bag` | `/camera/left/image` |",
        "`recovery` 3:4",
        "- [x] **Surgical Robotics**",
    ] {
        assert!(readme.contains(wanted), "{wanted:?} not in\n{readme}");
    }
    // Every frame's instruction, read back.
    let mut back = surgvla::export::lerobot::read::LeRobotSource::open(&out).expect("read");
    let episode = back.next().expect("an episode").expect("read");
    assert_eq!(
        episode.steps[0].other.last(),
        Some(&FeatureValue::Text("grasp the needle".into()))
    );
    let (code, _, stderr) = surgvla(&["validate", out.to_str().expect("utf-8")]);
    assert_eq!(code, 0, "{stderr}");
    // What the profile cannot write is refused before anything is written.
    for (extra, problem) in [
        (
            vec!["--profile", "open-h", "--to", "rlds"],
            "writes LeRobot",
        ),
        (
            vec!["--profile", "open-h", "--lerobot-version", "3.0"],
            "not --lerobot-version 3.0",
        ),
        (vec!["--split", "train=0:5"], "reaches past the 4 episodes"),
        (vec!["--split", "train=3"], "is not START:END"),
        (
            vec!["--profile", "open-h", "--depth", "d=/camera/depth"],
            "three channels only",
        ),
        (vec!["--depth", "left=/camera/depth"], "left is given twice"),
        (
            vec!["--split", "val=0:1", "--to", "rlds"],
            "LeRobot's info.json",
        ),
    ] {
        let refused = root.join("refused");
        let (code, _, stderr) = ingest(&refused, &extra);
        assert_eq!(code, 2, "{extra:?}: {stderr}");
        assert!(stderr.contains(problem), "{extra:?}: {stderr}");
        assert!(!refused.join("meta/info.json").exists());
    }
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn a_map_file_is_checked_and_its_topics_must_be_recorded() {
    let root = temp_root("ingest-map");
    std::fs::create_dir_all(&root).expect("root");
    let map = root.join("map.toml");
    let out = root.join("out");
    let map_arg = map.to_str().expect("utf-8");
    std::fs::write(
        &map,
        "[[feature]]\nname = \"action\"\ntopic = \"/ECM/measured_cp\"\nvalues = \"pose\"\n",
    )
    .expect("write");
    let (code, _, stderr) = ingest(&out, &["--map", map_arg]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(map_arg) && stderr.contains("the preset writes"),
        "{stderr}"
    );
    std::fs::write(
        &map,
        "[[feature]]\nname = \"observation.meta.ecm\"\ntopic = \"/ECM/measured_cp\"\nvalues = \"pose\"\n",
    )
    .expect("write");
    let (code, _, stderr) = ingest(&out, &["--map", map_arg]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("/ECM/measured_cp") && stderr.contains("ros1_raw_lz4.bag"),
        "{stderr}"
    );
    assert!(!out.join("meta/info.json").exists());
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn an_ingest_killed_mid_run_resumes_through_the_cli_to_the_same_bytes() {
    let root = temp_root("ingest-kill");
    let bag = fixture("ros1_raw_lz4.bag");
    let bag = bag.to_str().expect("utf-8");
    // 200 sessions (the same recording again and again), long enough to be killed mid-run.
    let args = |out: &Path| {
        let mut args = vec!["ingest"];
        args.extend(std::iter::repeat_n(bag, 200));
        let out = out.to_str().expect("utf-8").to_string();
        args.extend([
            "--camera",
            "left=/camera/left/image",
            "--lerobot-version",
            "2.1",
            // Episodes in parts (of 32 frames here): a kill may come within one.
            "--part-mib",
            "0.001",
        ]);
        args.extend(["--threads", "1", "--out"]);
        let mut args: Vec<String> = args.into_iter().map(String::from).collect();
        args.push(out);
        args
    };
    let (reference, killed) = (root.join("reference"), root.join("killed"));
    let reference_args = args(&reference);
    let (code, _, stderr) = surgvla(
        &reference_args
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    assert_eq!(code, 0, "{stderr}");
    let killed_args = args(&killed);
    let killed_args: Vec<&str> = killed_args.iter().map(String::as_str).collect();
    crate::util::kill_after_checkpoint(&killed_args, &killed);
    assert!(
        killed.join(INCOMPLETE_MARKER).exists(),
        "a killed run is marked incomplete"
    );
    let mut resume = killed_args.clone();
    resume.push("--resume");
    let (code, stdout, stderr) = surgvla(&resume);
    assert_eq!(code, 0, "{stderr}");
    let said = format!("{stdout}{stderr}");
    assert!(said.contains("resum"), "{said}");
    let (a, b) = (tree(&reference), tree(&killed));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs after the resume");
    }
    std::fs::remove_dir_all(root).ok();
}
