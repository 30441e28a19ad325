//! The RLDS format end to end through the CLI: `collect --format rlds` writes what `convert
//! --to rlds` makes of the same LeRobot dataset, converting RLDS to RLDS changes nothing, format
//! options are refused with the other format, and damaged shards are named. (The framing test
//! vectors and the Example round trip are unit tests; tensorflow_datasets reads the output in
//! `tests/interop/rlds/`.)

use crate::util::{surgvla, temp_root, tree};
use std::collections::BTreeMap;
use std::path::Path;
use surgvla::export::open_source;

const VERSION_DIR: &str = "surgvla_benchmark/1.0.0";
const SMALL: [&str; 4] = ["--tasks", "T1-1,T2-3", "--episodes-per-task", "2"];

fn run_ok(args: &[&str]) -> String {
    let (code, out, err) = surgvla(args);
    assert_eq!(code, 0, "surgvla {args:?}: {err}");
    out
}

fn collect(out: &Path, extra: &[&str]) {
    let mut args = vec!["collect", "--out", path(out)];
    args.extend(SMALL);
    args.extend(extra);
    run_ok(&args);
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// The dataset's files, without the run's report (its timings vary).
fn dataset_files(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = tree(root);
    files.remove("collect_report.json");
    files
}

#[test]
fn collect_rlds_writes_what_convert_makes_of_the_lerobot_dataset() {
    let lerobot = temp_root("rlds-lerobot");
    let direct = temp_root("rlds-direct");
    let converted = temp_root("rlds-converted");
    collect(&lerobot, &["--with-mask"]);
    collect(&direct, &["--with-mask", "--format", "rlds"]);
    let said = run_ok(&[
        "convert",
        path(&lerobot),
        "--to",
        "rlds",
        "--out",
        path(&converted),
    ]);
    assert!(said.contains("converted 4 episodes"), "{said}");
    let direct_files = dataset_files(&direct);
    let names: Vec<&String> = direct_files.keys().collect();
    assert_eq!(
        names,
        [
            "OPENVLA.md",
            "README.md",
            "surgvla_benchmark/1.0.0/dataset_info.json",
            "surgvla_benchmark/1.0.0/features.json",
            "surgvla_benchmark/1.0.0/surgvla.json",
            "surgvla_benchmark/1.0.0/surgvla_benchmark-train.tfrecord-00000-of-00001",
            "surgvla_manifest.json",
        ]
    );
    assert!(
        direct_files == dataset_files(&converted),
        "collect --format rlds and convert --to rlds differ"
    );

    // RLDS -> RLDS changes nothing (depth in millimetres survives the trip through metres).
    let again = temp_root("rlds-again");
    run_ok(&[
        "convert",
        path(&direct),
        "--to",
        "rlds",
        "--out",
        path(&again),
    ]);
    assert!(
        dataset_files(&again) == direct_files,
        "rlds -> rlds differs"
    );

    // RLDS -> LeRobot keeps every episode and its provenance.
    let back = temp_root("rlds-back");
    run_ok(&[
        "convert",
        &format!("{}/{VERSION_DIR}", path(&direct)),
        "--to",
        "lerobot",
        "--out",
        path(&back),
    ]);
    let original = open_source(&lerobot).expect("lerobot");
    let mut returned = open_source(&back).expect("lerobot from rlds");
    assert_eq!(returned.len(), original.len());
    assert_eq!(returned.info().features, original.info().features);
    for episode in original {
        let (a, b) = (
            episode.expect("read"),
            returned.next().expect("one").expect("read"),
        );
        assert_eq!(
            (
                a.meta.seed,
                &a.meta.task_code,
                a.meta.success,
                &a.meta.instruction
            ),
            (
                b.meta.seed,
                &b.meta.task_code,
                b.meta.success,
                &b.meta.instruction
            )
        );
        assert_eq!(a.steps.len(), b.steps.len());
        assert!(
            a.steps
                .iter()
                .zip(&b.steps)
                .all(|(x, y)| x.rgb == y.rgb && x.mask == y.mask && x.action == y.action)
        );
    }
}

#[test]
fn format_options_are_refused_with_the_other_format() {
    let out = temp_root("rlds-refused");
    for (args, named) in [
        (vec!["--format", "rlds", "--video"], "--video"),
        (
            vec!["--format", "rlds", "--lerobot-version", "2.1"],
            "--lerobot-version",
        ),
        (vec!["--rlds-name", "mine"], "--rlds-name"),
        (
            vec!["--format", "rlds", "--rlds-name", "Not-Snake"],
            "snake_case",
        ),
        (vec!["--format", "rlds", "--rlds-version", "1.0"], "x.y.z"),
        (
            vec!["--format", "rlds", "--rlds-image-key", "state"],
            "given twice",
        ),
    ] {
        let mut all = vec!["collect", "--out", path(&out)];
        all.extend(SMALL);
        all.extend(&args);
        let (code, _, err) = surgvla(&all);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(named), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} touched the output");
    }
    let (code, _, err) = surgvla(&[
        "convert",
        "/no/such/dataset",
        "--to",
        "rlds",
        "--out",
        path(&out),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("/no/such/dataset") && err.contains("does not exist"),
        "{err}"
    );
}

#[test]
fn damaged_shards_are_named_and_exit_1() {
    let good = temp_root("rlds-good");
    collect(&good, &["--format", "rlds", "--rlds-shard-mb", "1"]);
    let shards: Vec<String> = dataset_files(&good)
        .into_keys()
        .filter(|name| name.contains(".tfrecord-"))
        .collect();
    assert!(shards.len() >= 2, "{shards:?}");
    /// (what, how the first shard is harmed, what the error says).
    type Damage<'a> = (&'a str, &'a dyn Fn(&Path), &'a str);
    let damage: [Damage; 4] = [
        (
            "a flipped byte",
            &|shard| {
                let mut bytes = std::fs::read(shard).expect("read");
                let middle = bytes.len() / 2;
                bytes[middle] ^= 0x40;
                std::fs::write(shard, bytes).expect("write");
            },
            "CRC",
        ),
        (
            "a truncated shard",
            &|shard| {
                let bytes = std::fs::read(shard).expect("read");
                std::fs::write(shard, &bytes[..bytes.len() - 100]).expect("write");
            },
            "truncated",
        ),
        (
            "a missing shard",
            &|shard| std::fs::remove_file(shard).expect("remove"),
            "is missing",
        ),
        (
            "a wrong shardLengths",
            &|shard| {
                let info = shard.with_file_name("dataset_info.json");
                let text = std::fs::read_to_string(&info).expect("read");
                let mut json: serde_json::Value = serde_json::from_str(&text).expect("json");
                let first = &mut json["splits"][0]["shardLengths"][0];
                let count: u64 = first.as_str().expect("a count").parse().expect("number");
                *first = (count + 1).to_string().into();
                std::fs::write(&info, json.to_string()).expect("write");
            },
            "shardLengths",
        ),
    ];
    for (what, harm, said) in damage {
        let broken = temp_root("rlds-broken");
        for (name, bytes) in tree(&good) {
            let target = broken.join(&name);
            std::fs::create_dir_all(target.parent().expect("parent")).expect("dir");
            std::fs::write(target, bytes).expect("copy");
        }
        let shard = broken.join(&shards[0]);
        harm(&shard);
        let out = temp_root("rlds-broken-out");
        let (code, _, err) = surgvla(&[
            "convert",
            path(&broken),
            "--to",
            "lerobot",
            "--out",
            path(&out),
        ]);
        assert_eq!(code, 1, "{what}: {err}");
        let named = shard.display().to_string();
        assert!(err.contains(&named) && err.contains(said), "{what}: {err}");
        assert!(
            err.contains("reading the input dataset") && !err.contains("--resume"),
            "{what}: a damaged input is not resumable: {err}"
        );
    }
}

/// The committed RLDS feature tree is what the writer declares. After an intended change,
/// regenerate with `cargo run --release -- schema --format rlds --with-mask >
/// schemas/rlds_features.json`.
#[test]
fn rlds_schema_snapshot_matches_the_features() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("schemas/rlds_features.json");
    let committed: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).expect("schema file")).expect("json");
    let options = surgvla::export::rlds::RldsOptions::default();
    assert_eq!(
        committed,
        surgvla::export::rlds::features::features_json(&crate::util::info(true), &options)
    );
}

/// Another tool's features (a 14-D vector, an int64, a camera PNG) go to RLDS under their
/// paths (`observation/state`, `observation/wrist`) and come back, by name, unchanged, images
/// byte for byte; the dataset gets no surgvla.json, so reading it needs a frame rate.
#[test]
fn other_features_round_trip_through_rlds() {
    use std::collections::BTreeMap;
    let (dataset, episodes) = crate::util::foreign_dataset();
    let root = temp_root("rlds-other");
    let mut writer = surgvla::export::rlds::RldsWriter::create(&root, &dataset, Default::default())
        .expect("writer");
    surgvla::export::EpisodeSink::write_batch(&mut writer, &episodes).expect("write");
    surgvla::export::EpisodeSink::finish(&mut writer).expect("finish");
    assert!(!root.join(VERSION_DIR).join("surgvla.json").exists());
    assert!(open_source(&root).is_err(), "no frame rate given");
    let options = surgvla::export::SourceOptions {
        fps: Some(5),
        ..Default::default()
    };
    let mut source = surgvla::export::open_source_with(&root, &options).expect("source");
    let named = |info: &surgvla::export::DatasetInfo, values: &[surgvla::episode::FeatureValue]| {
        info.features
            .iter()
            .map(|f| f.name.clone())
            .zip(values.iter().cloned())
            .collect::<BTreeMap<_, _>>()
    };
    let read_info = source.info().clone();
    assert_eq!(read_info.robot_type, "unknown");
    for expected in &episodes {
        let read = source.next().expect("episode").expect("readable");
        assert_eq!(read.meta.instruction, expected.meta.instruction);
        assert_eq!(read.steps.len(), expected.steps.len());
        for (a, b) in read.steps.iter().zip(&expected.steps) {
            assert_eq!(named(&read_info, &a.other), named(&dataset, &b.other));
        }
    }
    assert!(source.next().is_none());
    let report = surgvla::export::validate::validate(&root, &Default::default()).expect("runs");
    assert!(report.valid, "{:#?}", report.errors);
}

#[test]
fn jpeg_rgb_is_verified_within_the_tolerance_and_copied_between_jpeg_datasets() {
    let lerobot = temp_root("rlds-jpeg-src");
    collect(&lerobot, &["--format", "lerobot"]);
    let jpeg = temp_root("rlds-jpeg");
    run_ok(&[
        "convert",
        path(&lerobot),
        "--to",
        "rlds",
        "--rlds-image-encoding",
        "jpeg",
        "--rlds-jpeg-quality",
        "90",
        "--verify",
        "--out",
        path(&jpeg),
    ]);
    let features =
        std::fs::read_to_string(jpeg.join("surgvla_benchmark/1.0.0/features.json")).expect("read");
    assert!(
        features.contains("\"encodingFormat\": \"jpeg\""),
        "{features}"
    );
    assert!(features.contains("JPEG, quality 90"));
    // JPEG read back is JPEG written again: the same bytes, not a second generation.
    let again = temp_root("rlds-jpeg-again");
    run_ok(&[
        "convert",
        path(&jpeg),
        "--to",
        "rlds",
        "--rlds-image-encoding",
        "jpeg",
        "--verify",
        "--out",
        path(&again),
    ]);
    let shards = |root: &Path| {
        dataset_files(root)
            .into_iter()
            .filter(|(name, _)| name.contains(".tfrecord"))
            .map(|(_, bytes)| bytes)
            .collect::<Vec<_>>()
    };
    assert_eq!(shards(&jpeg), shards(&again));
    // Within the tolerance is not anything goes: each frame one step late differs.
    struct Late(Box<dyn surgvla::export::EpisodeSource + Send>);
    impl surgvla::export::EpisodeSource for Late {
        fn info(&self) -> &surgvla::export::DatasetInfo {
            self.0.info()
        }
        fn len(&self) -> u64 {
            self.0.len()
        }
    }
    impl Iterator for Late {
        type Item = Result<surgvla::episode::Episode, surgvla::export::ExportError>;
        fn next(&mut self) -> Option<Self::Item> {
            self.0.next().map(|e| {
                e.map(|mut episode| {
                    let first = episode.steps[0].rgb.clone();
                    for i in (1..episode.steps.len()).rev() {
                        episode.steps[i].rgb = episode.steps[i - 1].rgb.clone();
                    }
                    episode.steps[0].rgb = first;
                    episode.encoded.clear();
                    episode
                })
            })
        }
    }
    let mut late = Late(open_source(&lerobot).expect("open"));
    let summary = surgvla::export::Summary::default();
    let differences =
        surgvla::export::verify::verify_output(&mut late, &jpeg, &summary).expect("verify");
    assert!(
        differences.iter().any(|d| d.contains("RGB differs")),
        "{differences:?}"
    );
    // Replay compares the JPEG frames within the tolerance too.
    let (code, _, err) = surgvla(&["validate", path(&jpeg), "--replay"]);
    assert_eq!(code, 0, "{err}");
}

/// OPENVLA.md says what the gripper holds: absolute by default; with `--gripper-encoding
/// pulse`, the pulse, and a standardize transform that rebuilds the absolute gripper (the
/// interop test runs it through tf.data).
#[test]
fn the_openvla_guide_describes_the_gripper_the_data_holds() {
    let absolute = temp_root("rlds-guide-absolute");
    let pulse = temp_root("rlds-guide-pulse");
    collect(&absolute, &["--format", "rlds"]);
    collect(&pulse, &["--format", "rlds", "--gripper-encoding", "pulse"]);
    let read = |root: &Path| std::fs::read_to_string(root.join("OPENVLA.md")).expect("guide");
    let (absolute, pulse) = (read(&absolute), read(&pulse));
    assert!(absolute.contains("absolute, **1 = open, 0 = closed**"));
    assert!(!absolute.contains("pulse") && !absolute.contains("tf.scan"));
    assert!(pulse.contains("gripper as a **pulse**") && pulse.contains("tf.scan("));
    assert!(!pulse.contains("absolute, **1 = open"));
    assert!(!pulse.contains("output.  The") && !absolute.contains("output.  The"));
}

/// A TFDS data directory holding several datasets (as `~/tensorflow_datasets` does) is named
/// as such with its datasets listed (exit 2), and each is read when given as `<dir>/<name>`.
#[test]
fn a_data_directory_of_several_datasets_lists_them() {
    let source = temp_root("rlds-several-source");
    collect(&source, &["--format", "rlds"]);
    let data_dir = temp_root("rlds-several");
    for name in ["bridge_like", "surgvla_benchmark"] {
        for (relative, bytes) in tree(&source.join("surgvla_benchmark")) {
            let path = data_dir.join(name).join(relative);
            std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
            std::fs::write(path, bytes).expect("copy");
        }
    }
    for command in ["validate", "info"] {
        let (code, out, err) = surgvla(&[command, path(&data_dir)]);
        assert_eq!(code, 2, "{command}: {out}{err}");
        assert!(
            err.contains("several RLDS datasets (bridge_like, surgvla_benchmark)"),
            "{err}"
        );
    }
    let one = data_dir.join("bridge_like");
    let (code, out, err) = surgvla(&["info", path(&one)]);
    assert_eq!(code, 0, "{out}{err}");
    // Its tasks are listed by task id, with their episodes and instructions.
    assert!(out.contains("tasks (episodes, instructions)"), "{out}");
    assert!(out.contains("  T1-1        2  pick up the gauze"), "{out}");
    let out_dir = temp_root("rlds-several-out");
    run_ok(&[
        "convert",
        path(&one),
        "--to",
        "lerobot",
        "--out",
        path(&out_dir),
    ]);
}

/// `convert --map` on an RLDS dataset another tool wrote: the map's features are made of the
/// keys it names (concatenated, integers joining floats exactly), `task` says where the
/// instruction is; what is left out is named on stderr; a key the dataset lacks, a
/// recording's map and a map for a dataset that is not another tool's RLDS exit 2.
#[test]
fn a_map_file_names_the_features_of_another_tools_rlds() {
    let (dataset, episodes) = crate::util::foreign_dataset();
    let root = temp_root("rlds-map");
    let mut writer = surgvla::export::rlds::RldsWriter::create(&root, &dataset, Default::default())
        .expect("writer");
    surgvla::export::EpisodeSink::write_batch(&mut writer, &episodes).expect("write");
    surgvla::export::EpisodeSink::finish(&mut writer).expect("finish");
    let map = root.join("map.toml");
    let write_map = |text: &str| std::fs::write(&map, text).expect("map");
    write_map(
        "[[feature]]\nname = \"action\"\nkeys = [\"observation/state\", \"steps/observation/gripper_count\"]\n\n[[feature]]\nname = \"task\"\nkeys = [\"instruction/text\"]\n",
    );
    let out = temp_root("rlds-map-out");
    let convert = |out: &Path, input: &Path| {
        surgvla(&[
            "convert",
            path(input),
            "--to",
            "lerobot",
            "--fps",
            "5",
            "--map",
            path(&map),
            "--out",
            path(out),
            "--verify",
        ])
    };
    let (code, _, err) = convert(&out, &root);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("episode_metadata/file_path: per episode, carried"),
        "{err}"
    );
    assert!(
        err.contains("action = steps/observation/state + steps/observation/gripper_count"),
        "{err}"
    );
    let options = surgvla::export::SourceOptions::default();
    let mut source = surgvla::export::open_source_with(&out, &options).expect("output");
    let info = source.info().clone();
    let action = info
        .features
        .iter()
        .position(|f| f.name == "action")
        .expect("action");
    assert_eq!(info.features[action].shape, [15]);
    for expected in &episodes {
        let read = source.next().expect("episode").expect("readable");
        for (k, (step, original)) in read.steps.iter().zip(&expected.steps).enumerate() {
            use surgvla::episode::FeatureValue;
            let (FeatureValue::Float32(state), FeatureValue::Int64(count)) =
                (&original.other[0], &original.other[1])
            else {
                panic!("the fixture's layout");
            };
            let mut joined = state.clone();
            joined.push(count[0] as f32);
            assert_eq!(step.other[action], FeatureValue::Float32(joined));
            assert_eq!(
                read.meta.instruction_at(k),
                format!("step {k} of task {}", expected.meta.index % 2)
            );
        }
    }
    for (text, said) in [
        (
            "[[feature]]\nname = \"action\"\nkeys = [\"action/world_vector\"]\n",
            "steps/action/world_vector is not a numeric key",
        ),
        (
            "[[feature]]\nname = \"x\"\ntopic = \"/a\"\nkeys = [\"observation/state\"]\n",
            "are for recordings",
        ),
        (
            "[[feature]]\nname = \"task\"\nkeys = [\"observation/state\"]\n",
            "not a text or integer key",
        ),
        (
            "[[feature]]\nname = \"observation.state\"\nkeys = [\"observation/gripper_count\"]\n",
            "which the map's feature of that name already is",
        ),
    ] {
        write_map(text);
        let (code, _, err) = convert(&temp_root("rlds-map-bad"), &root);
        assert_eq!(code, 2, "{said}: {err}");
        assert!(err.contains(said) && err.contains("--map"), "{err}");
    }
    write_map("[[feature]]\nname = \"task\"\nkeys = [\"instruction/text\"]\n");
    let (code, _, err) = convert(&temp_root("rlds-map-lerobot"), &out);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--map is for RLDS datasets another tool wrote"),
        "{err}"
    );
}
