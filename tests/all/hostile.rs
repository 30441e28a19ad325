//! Other people's datasets as an attacker or an unlucky operator would make them: names and
//! templates in the metadata that point outside the dataset, metadata files that never end,
//! FIFOs, folders and link loops where files should be, links inside an interrupted dataset,
//! absurd thread counts, seeded mutations of every format's metadata and binary files and of
//! the recordings `ingest` reads. Every command ends within [`LIMIT`] (60 s) and
//! [`MAX_RSS_BYTES`] (1 GiB, sampled while it runs) with exit 0, 1 or 2, never a panic or an
//! abort, and a sentinel folder beside the dataset and the output is byte-identical afterwards.

use crate::util::{temp_root, tree};
use serde_json::Value;
use std::path::Path;
use std::time::{Duration, Instant};

/// The peak resident memory of process `pid` so far (Linux's VmHWM), in bytes.
fn peak_rss_bytes(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmHWM:"))
        .and_then(|rest| {
            rest.trim()
                .trim_end_matches("kB")
                .trim()
                .parse::<u64>()
                .ok()
        })
        .map_or(0, |kib| kib * 1024)
}

/// The most memory any run may take: the bound the hostile tests state.
const MAX_RSS_BYTES: u64 = 1 << 30;

/// Runs the binary with a deadline: (exit code, stderr then stdout). A run past the deadline is
/// killed and fails the test (a hang), as does a run whose peak resident memory, sampled while
/// it runs, passes [`MAX_RSS_BYTES`].
fn run(args: &[&str], limit: Duration) -> (i32, String) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn surgvla");
    let started = Instant::now();
    let mut peak = 0;
    loop {
        peak = peak.max(peak_rss_bytes(child.id()));
        assert!(
            peak <= MAX_RSS_BYTES,
            "surgvla {args:?} took {} MiB of memory",
            peak >> 20
        );
        if let Some(status) = child.try_wait().expect("wait") {
            let mut text = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().expect("stderr"), &mut text)
                .expect("stderr");
            std::io::Read::read_to_string(&mut child.stdout.take().expect("stdout"), &mut text)
                .expect("stdout");
            return (status.code().unwrap_or(-1), text);
        }
        if started.elapsed() > limit {
            child.kill().ok();
            panic!("surgvla {args:?} hung (killed after {limit:?})");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

const LIMIT: Duration = Duration::from_secs(60);

/// `collect --tasks T1-1 --episodes-per-task EPISODES EXTRA... --out OUT`, which must succeed.
fn collect(out: &str, episodes: &str, extra: &[&str]) {
    let mut args = vec![
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        episodes,
    ];
    args.extend(extra);
    args.extend(["--out", out]);
    let (code, stderr) = run(&args, LIMIT);
    assert_eq!(code, 0, "{args:?}: {stderr}");
}

/// A folder beside the datasets with a file in it: must be byte-identical after every command.
fn sentinel(parent: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let folder = parent.join("outside");
    std::fs::create_dir_all(&folder).expect("sentinel");
    std::fs::write(folder.join("keep.txt"), b"not yours").expect("sentinel");
    tree(&folder)
}

/// A change to a metadata document.
type Edit = Box<dyn Fn(&mut Value)>;

fn edit_json(path: &Path, edit: impl FnOnce(&mut Value)) {
    let mut value: Value =
        serde_json::from_slice(&std::fs::read(path).expect("read")).expect("json");
    edit(&mut value);
    std::fs::write(path, serde_json::to_vec_pretty(&value).expect("json")).expect("write");
}

fn copy_tree(from: &Path, to: &Path) {
    for (relative, bytes) in tree(from) {
        let path = to.join(relative);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("copy");
    }
}

/// Runs `args` (with `{in}` and `{out}` replaced) and checks the run ended with `expected`,
/// never a panic, and touched nothing in the sentinel folder.
fn expect_exit(parent: &Path, args: &[&str], expected: i32, what: &str) -> String {
    let before = tree(&parent.join("outside"));
    let (code, stderr) = run(args, LIMIT);
    assert_eq!(code, expected, "{what}: surgvla {args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{what}: {stderr}");
    assert_eq!(
        tree(&parent.join("outside")),
        before,
        "{what}: the sentinel changed"
    );
    stderr
}

#[test]
fn lerobot_names_and_templates_that_leave_the_dataset_are_refused() {
    let parent = temp_root("hostile-lerobot");
    sentinel(&parent);
    // Two shards, so that merge has two inputs to join.
    let shard = |i: usize| parent.join(format!("base-{i}"));
    for i in 0..2 {
        let out = shard(i);
        collect(
            out.to_str().expect("utf-8"),
            "2",
            &["--video", "h264", "--shard", &format!("{i}/2")],
        );
    }
    let base = shard(0);
    let key = "observation.images.endoscope";
    // A video in the sentinel folder, which a path pointing outside would read and copy.
    let outside_video = parent.join("outside/videos/x/chunk-000/file-000.mp4");
    std::fs::create_dir_all(outside_video.parent().expect("parent")).expect("mkdir");
    std::fs::copy(
        base.join(format!("videos/{key}/chunk-000/file-000.mp4")),
        &outside_video,
    )
    .expect("copy");
    let absolute = format!(
        "{}/outside/videos/{{video_key}}/chunk-000/file-000.mp4",
        parent.display()
    );
    let cases: Vec<(&str, Edit)> = vec![
        (
            "a video key with ../",
            Box::new(move |info: &mut Value| {
                let features = info["features"].as_object_mut().expect("features");
                let feature = features.shift_remove(key).expect("rgb");
                features.insert("../../../x".into(), feature);
            }),
        ),
        (
            "a video_path template with ../",
            Box::new(|info: &mut Value| {
                info["video_path"] =
                    "../outside/videos/x/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4".into();
            }),
        ),
        (
            "a data_path template with ../ (which no reader follows: refused all the same)",
            Box::new(|info: &mut Value| {
                info["data_path"] =
                    "../../etc/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet".into();
            }),
        ),
        (
            "an absolute video_path",
            Box::new(move |info: &mut Value| {
                info["video_path"] = absolute.clone().into();
            }),
        ),
        (
            "a video key holding its own placeholder",
            Box::new(move |info: &mut Value| {
                let features = info["features"].as_object_mut().expect("features");
                let feature = features.shift_remove(key).expect("rgb");
                features.insert("{video_key:1d}".into(), feature);
                info["video_path"] =
                    "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4".into();
            }),
        ),
        (
            "a padding width over 65535",
            Box::new(|info: &mut Value| {
                info["video_path"] =
                    "videos/{video_key}/chunk-{chunk_index:070000d}/file-{file_index:03d}.mp4"
                        .into();
            }),
        ),
    ];
    for (i, (what, edit)) in cases.iter().enumerate() {
        let second = parent.join(format!("case-{i}-1"));
        copy_tree(&shard(1), &second);
        edit_json(&second.join("meta/info.json"), edit);
        let second = second.to_str().expect("utf-8");
        let dataset = parent.join(format!("case-{i}"));
        copy_tree(&base, &dataset);
        edit_json(&dataset.join("meta/info.json"), edit);
        let dataset = dataset.to_str().expect("utf-8");
        let out = parent.join(format!("out-{i}"));
        let out = out.to_str().expect("utf-8");
        // A key holding its own placeholder is a name, not an escape: it must only end.
        let escapes = !what.contains("placeholder");
        let stderr = expect_exit(&parent, &["validate", dataset], 1, what);
        assert!(!escapes || stderr.contains("[paths]"), "{what}: {stderr}");
        let stderr = expect_exit(
            &parent,
            &[
                "convert", dataset, "--to", "lerobot", "--video", "h264", "--out", out,
            ],
            1,
            what,
        );
        assert!(
            !escapes || stderr.contains("cannot be a path inside the dataset"),
            "{what}: {stderr}"
        );
        expect_exit(
            &parent,
            &["merge", dataset, second, "--out", &format!("{out}-m")],
            1,
            what,
        );
        expect_exit(&parent, &["info", dataset], 1, what);
        if escapes {
            let (code, stderr) = run(
                &[
                    "eval",
                    "--policy",
                    "replay",
                    "--dataset",
                    dataset,
                    "--tasks",
                    "T1-1",
                    "--trials",
                    "1",
                    "--out",
                    &format!("{out}-eval"),
                ],
                LIMIT,
            );
            assert!(
                (1..=2).contains(&code) && !stderr.contains("panicked"),
                "{what}: eval exit {code}: {stderr}"
            );
        }
    }
}

#[test]
fn an_rlds_name_that_leaves_the_dataset_is_refused() {
    let parent = temp_root("hostile-rlds");
    sentinel(&parent);
    let dataset = parent.join("rlds");
    let text = dataset.to_str().expect("utf-8");
    collect(text, "1", &["--format", "rlds"]);
    let info = std::fs::read_dir(&dataset)
        .expect("read")
        .flatten()
        .map(|e| e.path())
        .find_map(|name| {
            let version = std::fs::read_dir(name).ok()?.flatten().next()?.path();
            let info = version.join("dataset_info.json");
            info.exists().then_some(info)
        })
        .expect("dataset_info.json");
    edit_json(&info, |value| value["name"] = "../../outside/x".into());
    let stderr = expect_exit(&parent, &["validate", text], 1, "validate");
    assert!(stderr.contains("paths"), "{stderr}");
    let out = parent.join("out");
    let stderr = expect_exit(
        &parent,
        &[
            "convert",
            text,
            "--to",
            "lerobot",
            "--out",
            out.to_str().expect("utf-8"),
        ],
        1,
        "convert",
    );
    assert!(
        stderr.contains("cannot be a path inside the dataset"),
        "{stderr}"
    );
}

#[test]
fn metadata_that_never_ends_is_not_read() {
    let parent = temp_root("hostile-zero");
    sentinel(&parent);
    let dataset = parent.join("lerobot");
    let text = dataset.to_str().expect("utf-8");
    collect(text, "1", &[]);
    for file in ["meta/stats.json", "meta/info.json"] {
        let path = dataset.join(file);
        std::fs::remove_file(&path).expect("remove");
        std::os::unix::fs::symlink("/dev/zero", &path).expect("link");
    }
    let stderr = expect_exit(&parent, &["validate", text], 1, "validate");
    assert!(stderr.contains("not a regular file"), "{stderr}");
    let out = parent.join("out");
    let out = out.to_str().expect("utf-8");
    expect_exit(
        &parent,
        &["convert", text, "--to", "rlds", "--out", out],
        1,
        "convert",
    );
    expect_exit(&parent, &["info", text], 1, "info");
}

#[test]
fn resume_never_writes_or_deletes_through_a_link() {
    let parent = temp_root("hostile-resume");
    sentinel(&parent);
    let dataset = parent.join("mcap");
    let text = dataset.to_str().expect("utf-8");
    let args = [
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "1",
        "--format",
        "mcap",
        "--out",
        text,
    ];
    assert_eq!(run(&args, LIMIT).0, 0);
    // An interrupted dataset (the marker back in place) holding a link to the sentinel folder.
    std::fs::write(dataset.join(surgvla::export::INCOMPLETE_MARKER), b"{}").expect("marker");
    std::os::unix::fs::symlink(parent.join("outside"), dataset.join("linked")).expect("link");
    let mut resume = args.to_vec();
    resume.push("--resume");
    let stderr = expect_exit(&parent, &resume, 2, "resume");
    assert!(stderr.contains("symbolic link linked"), "{stderr}");
}

#[test]
fn every_command_takes_the_same_thread_rule() {
    let parent = temp_root("hostile-threads");
    let out = parent.join("out");
    let out = out.to_str().expect("utf-8");
    let too_many = (8 * surgvla::collect::slot::cores() + 1).to_string();
    for args in [
        vec!["collect", "--tasks", "T1-1", "--out", out],
        vec!["convert", out, "--to", "rlds", "--out", out],
        vec!["merge", out, out, "--out", out],
        vec!["validate", out],
        vec!["eval", "--out", out],
    ] {
        let mut args = args.clone();
        args.extend(["--threads", too_many.as_str()]);
        let (code, stderr) = run(&args, LIMIT);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(stderr.contains("per core"), "{args:?}: {stderr}");
    }
}

#[test]
fn a_conversion_resumes_only_from_the_input_it_started_with() {
    use surgvla::export::rlds::RldsOptions;
    use surgvla::export::{SourceOptions, open_sink, open_source_with};
    let parent = temp_root("hostile-input");
    let input = |seed: &str| {
        let path = parent.join(format!("input-{seed}"));
        collect(path.to_str().expect("utf-8"), "2", &["--seed", seed]);
        path
    };
    let (a, b) = (input("1"), input("2"));
    let out = parent.join("out");
    {
        // A conversion of A killed after its first episode.
        let mut source = open_source_with(&a, &SourceOptions::default()).expect("source");
        let info = source.info().clone();
        assert!(info.input.is_some());
        let options = RldsOptions::default();
        let mut sink = open_sink(&out, &info, &options, false).expect("sink");
        let first = source.next().expect("one").expect("read");
        sink.write_batch(&[first]).expect("write");
    }
    let out_text = out.to_str().expect("utf-8");
    let convert = |input: &Path| {
        let input = input.to_str().expect("utf-8").to_string();
        run(
            &[
                "convert", &input, "--to", "rlds", "--out", out_text, "--resume",
            ],
            LIMIT,
        )
    };
    let (code, stderr) = convert(&b);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("input"), "{stderr}");
    let (code, stderr) = convert(&a);
    assert_eq!(code, 0, "{stderr}");
    // The same bytes as an uninterrupted conversion (the input's identity is not in them).
    let fresh = parent.join("fresh");
    let (code, _) = run(
        &[
            "convert",
            a.to_str().expect("utf-8"),
            "--to",
            "rlds",
            "--out",
            fresh.to_str().expect("utf-8"),
        ],
        LIMIT,
    );
    assert_eq!(code, 0);
    let without_report = |root: &Path| {
        let mut files = tree(root);
        files.retain(|name, _| !name.ends_with("report.json"));
        files
    };
    assert!(
        without_report(&out) == without_report(&fresh),
        "resumed differs"
    );
}

#[test]
fn totals_that_disagree_with_the_data_fail_the_conversion() {
    let parent = temp_root("hostile-totals");
    sentinel(&parent);
    let base = parent.join("base");
    collect(base.to_str().expect("utf-8"), "2", &[]);
    // info.json claiming 10^12 episodes; the only data file deleted.
    let claimed = parent.join("claimed");
    copy_tree(&base, &claimed);
    edit_json(&claimed.join("meta/info.json"), |info| {
        info["total_episodes"] = 1_000_000_000_000u64.into();
    });
    let emptied = parent.join("emptied");
    copy_tree(&base, &emptied);
    std::fs::remove_file(emptied.join("data/chunk-000/file-000.parquet")).expect("remove");
    // A stray data file (a copy of the first) in the input: the input's fault, not the output's.
    let stray = parent.join("stray");
    copy_tree(&base, &stray);
    std::fs::copy(
        stray.join("data/chunk-000/file-000.parquet"),
        stray.join("data/chunk-000/file-001.parquet"),
    )
    .expect("copy");
    for (dataset, said) in [
        (&stray, "reading the input dataset"),
        (&claimed, "says the dataset holds 1000000000000 episodes"),
        (
            &emptied,
            "says the dataset holds 2 episodes; its data files hold 0",
        ),
    ] {
        let out = parent.join("out");
        let stderr = expect_exit(
            &parent,
            &[
                "convert",
                dataset.to_str().expect("utf-8"),
                "--to",
                "rlds",
                "--out",
                out.to_str().expect("utf-8"),
            ],
            1,
            said,
        );
        assert!(stderr.contains(said), "{stderr}");
        assert!(!stderr.contains("--resume"), "{stderr}");
        assert!(
            !out.join("surgvla_benchmark").exists()
                || surgvla::export::DatasetDir::is_interrupted(&out),
            "a half-written output must not look complete"
        );
        std::fs::remove_dir_all(&out).ok();
    }
}

/// Every JSON metadata file under `root` (relative paths, sorted).
fn json_files(root: &Path) -> Vec<String> {
    files_where(root, |name| {
        name.ends_with(".json") || name.ends_with(".zarray")
    })
}

/// Every binary file under `root` that carries structure a reader trusts: parquet footers,
/// TFRecord lengths, MCAP records and index, zarr chunks (relative paths, sorted).
fn binary_files(root: &Path) -> Vec<String> {
    files_where(root, |name| {
        [".parquet", ".mcap", ".mp4", ".png", ".tiff", ".ply", ".pcd"]
            .iter()
            .any(|ending| name.ends_with(ending))
            || name.contains(".tfrecord-")
            || name
                .rsplit('/')
                .next()
                .is_some_and(|last| last.split('.').all(|part| part.parse::<u64>().is_ok()))
    })
}

fn files_where(root: &Path, keep: impl Fn(&str) -> bool) -> Vec<String> {
    let mut files: Vec<String> = tree(root).into_keys().filter(|name| keep(name)).collect();
    files.sort();
    files
}

/// Replaces one value, chosen by `pick`, somewhere in `value` (depth first).
fn mutate(value: &mut Value, pick: &mut dyn FnMut(usize) -> usize, hostile: &Value) {
    let children: usize = match value {
        Value::Object(map) => map.len(),
        Value::Array(items) => items.len().min(8),
        _ => 0,
    };
    // Stop here a third of the time, or at a leaf.
    if children == 0 || pick(3) == 0 {
        *value = hostile.clone();
        return;
    }
    let child = pick(children);
    match value {
        Value::Object(map) => {
            if let Some((_, v)) = map.iter_mut().nth(child) {
                mutate(v, pick, hostile);
            }
        }
        Value::Array(items) => mutate(&mut items[child], pick, hostile),
        _ => {}
    }
}

/// Values that break metadata: paths out, hanging templates, absurd totals and shapes.
fn hostile_values() -> Vec<Value> {
    vec![
        serde_json::json!("../../outside/keep.txt"),
        serde_json::json!("/etc/passwd"),
        serde_json::json!("videos/{video_key:1d}/{chunk_index:099999d}"),
        serde_json::json!(1_000_000_000_000_000_000u64),
        serde_json::json!(-1),
        serde_json::json!(1e308),
        serde_json::json!([]),
        serde_json::json!({}),
        serde_json::json!(""),
        serde_json::json!(null),
        serde_json::json!([4_000_000_000u64, 4_000_000_000u64, 3]),
    ]
}

/// Changes a JSON document: one value somewhere replaced by a hostile one.
fn mutate_json(bytes: &[u8], rng: &mut surgvla::rng::SplitMix64) -> Option<(Vec<u8>, String)> {
    let hostile = hostile_values();
    let mut json: Value = serde_json::from_slice(bytes).ok()?;
    let value = &hostile[(rng.next_u64() % hostile.len() as u64) as usize];
    let mut pick = |n: usize| (rng.next_u64() % n as u64) as usize;
    mutate(&mut json, &mut pick, value);
    Some((serde_json::to_vec(&json).expect("json"), value.to_string()))
}

/// Changes a binary file as a lying writer or a bad disk would: a length or count field made
/// huge (0xff bytes), bytes zeroed, or the file cut short; within the last 64 bytes (footers,
/// indexes) half of the time.
fn mutate_bytes(bytes: &[u8], rng: &mut surgvla::rng::SplitMix64) -> Option<(Vec<u8>, String)> {
    if bytes.is_empty() {
        return None;
    }
    let len = bytes.len() as u64;
    let at = if rng.next_u64().is_multiple_of(2) {
        len.saturating_sub(1 + rng.next_u64() % 64.min(len))
    } else {
        rng.next_u64() % len
    } as usize;
    let mut out = bytes.to_vec();
    let how = match rng.next_u64() % 3 {
        0 => {
            let end = (at + 4).min(out.len());
            out[at..end].fill(0xff);
            "0xff"
        }
        1 => {
            let end = (at + 8).min(out.len());
            out[at..end].fill(0);
            "zeros"
        }
        _ => {
            out.truncate(at);
            "cut"
        }
    };
    Some((out, format!("{how} at byte {at} of {len}")))
}

/// What a mutator makes of a file: the new bytes and a description, or None to skip the file.
type Mutator = fn(&[u8], &mut surgvla::rng::SplitMix64) -> Option<(Vec<u8>, String)>;

/// Collects one small dataset per format, then, for `rounds` seeded mutations of one of its
/// files (chosen among `files`), runs every command that reads a dataset on it (validate, info,
/// convert, merge with the unmutated dataset, eval replaying it): each ends within the time
/// limit with exit 0, 1 or 2 (never a panic or an abort), and nothing beside the dataset or
/// the outputs changes.
fn every_command_survives(
    label: &str,
    seed: u64,
    rounds: usize,
    files: fn(&Path) -> Vec<String>,
    mutator: Mutator,
) {
    // A deeper local run: SURGVLA_MUTATION_SEED=N SURGVLA_MUTATION_ROUNDS=M.
    let from_env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<u64>().ok());
    let seed = from_env("SURGVLA_MUTATION_SEED").unwrap_or(seed);
    let rounds = from_env("SURGVLA_MUTATION_ROUNDS").map_or(rounds, |r| r as usize);
    let parent = temp_root(label);
    sentinel(&parent);
    let formats: [(&str, &[&str]); 8] = [
        ("lerobot-png", &[]),
        ("lerobot", &["--video", "h264"]),
        ("lerobot-av1", &["--video", "av1"]),
        ("rlds", &["--format", "rlds"]),
        ("zarr", &["--format", "zarr"]),
        ("mcap", &["--format", "mcap"]),
        ("ply", &["--format", "ply"]),
        ("pcd", &["--format", "pcd"]),
    ];
    let mut rng = surgvla::rng::SplitMix64::new(seed);
    for (name, extra) in formats {
        let base = parent.join(format!("base-{name}"));
        let base_text = base.to_str().expect("utf-8").to_string();
        collect(&base_text, "1", extra);
        let files = files(&base);
        assert!(!files.is_empty(), "{name}");
        let mut mutated = 0;
        for round in 0..rounds {
            let dataset = parent.join(format!("{name}-{round}"));
            copy_tree(&base, &dataset);
            let file = &files[(rng.next_u64() % files.len() as u64) as usize];
            let path = dataset.join(file);
            let Some((bytes, how)) = mutator(&std::fs::read(&path).expect("read"), &mut rng) else {
                continue;
            };
            std::fs::write(&path, bytes).expect("write");
            mutated += 1;
            let text = dataset.to_str().expect("utf-8").to_string();
            let out = parent.join(format!("out-{name}-{round}"));
            let out = out.to_str().expect("utf-8").to_string();
            let what = format!("{name} round {round}: {file} <- {how}");
            let merged = format!("{out}-merged");
            let eval = format!("{out}-eval");
            let mut verdicts = Vec::new();
            for command in [
                vec!["validate", text.as_str()],
                vec!["validate", text.as_str(), "--quick"],
                vec!["info", text.as_str()],
                vec!["convert", &text, "--to", "rlds", "--out", &out],
                vec!["merge", &base_text, &text, "--out", &merged],
                vec![
                    "eval",
                    "--policy",
                    "replay",
                    "--dataset",
                    &text,
                    "--tasks",
                    "T1-1",
                    "--trials",
                    "1",
                    "--record-failures",
                    "0",
                    "--out",
                    &eval,
                ],
            ] {
                let before = tree(&parent.join("outside"));
                let (code, stderr) = run(&command, LIMIT);
                assert!(
                    (0..=2).contains(&code),
                    "{what}: {command:?} exit {code}: {stderr}"
                );
                assert!(!stderr.contains("panicked"), "{what}: {stderr}");
                assert_eq!(
                    tree(&parent.join("outside")),
                    before,
                    "{what}: the sentinel changed"
                );
                verdicts.push((code, stderr));
            }
            // `info` runs the quick check; the quick check reads less than the full pass (the
            // checksums of metadata only, samples of images and video) and never judges more
            // strictly.
            let [(full, full_text), (quick, quick_text), (info, _)] = &verdicts[..3] else {
                unreachable!("three checks ran")
            };
            assert_eq!(
                info, quick,
                "{what}: info and validate --quick differ: {quick_text}"
            );
            assert!(
                *quick == 0 || full == quick,
                "{what}: --quick exit {quick}, the full pass {full}: {quick_text} / {full_text}"
            );
        }
        assert!(mutated > 0, "{name}: nothing was mutated");
    }
}

/// Seeded mutations of every format's JSON metadata (paths, templates, shapes, totals, sizes).
#[test]
fn mutated_metadata_never_panics_hangs_or_escapes() {
    every_command_survives("hostile-fuzz", 24, 24, json_files, mutate_json);
}

/// Seeded mutations of every format's binary files (parquet footers and row groups, TFRecord
/// lengths, MCAP records and summary, zarr chunks, PNG images in parquet cells, PNG and TIFF
/// headers, MP4 boxes with AV1 and H.264 streams, PLY and PCD headers and bodies).
#[test]
fn mutated_binary_files_never_panic_hang_or_escape() {
    every_command_survives("hostile-bytes", 2, 24, binary_files, mutate_bytes);
}

#[test]
fn video_mode_without_a_camera_is_the_users_mistake() {
    use surgvla::error::HasKind as _;
    use surgvla::export::lerobot::{LeRobotOptions, VideoOptions};
    use surgvla::export::open_sink;
    let parent = temp_root("hostile-video");
    let (mut info, _) = crate::util::foreign_dataset();
    // Without its 3-channel camera (which video mode would encode), nothing can be video.
    info.features
        .retain(|f| f.dtype != surgvla::episode::Dtype::Image);
    let options = LeRobotOptions {
        video: Some(VideoOptions::default()),
        ..LeRobotOptions::default()
    };
    let error = open_sink(&parent.join("out"), &info, &options, false)
        .err()
        .expect("refused");
    assert_eq!(error.kind(), surgvla::error::ErrorKind::Usage, "{error}");
    assert!(error.to_string().contains("needs an RGB camera"), "{error}");
    assert!(!parent.join("out").exists(), "nothing written");
}

#[test]
fn a_foreign_float_image_is_not_made_rlds_depth() {
    use surgvla::episode::FeatureValue;
    use surgvla::error::HasKind as _;
    use surgvla::export::open_sink;
    use surgvla::export::rlds::RldsOptions;
    let parent = temp_root("hostile-tiff");
    let (info, mut episodes) = crate::util::foreign_dataset();
    let tiff = surgvla::media::tiff::encode_f32_tiff(10, 8, &[0.5; 80]);
    for step in &mut episodes[0].steps {
        step.other[2] = FeatureValue::Image(tiff.clone());
    }
    let options = RldsOptions::default();
    let mut sink = open_sink(&parent.join("out"), &info, &options, false).expect("open");
    let error = sink.write_batch(&episodes[..1]).expect_err("refused");
    assert_eq!(error.kind(), surgvla::error::ErrorKind::Usage, "{error}");
    // One-channel float TIFFs where the feature declares three channels: not RLDS's to hold.
    let message = error.to_string();
    assert!(
        message.contains(
            "observation.images.wrist: episode 0 holds images other than one-channel float TIFFs"
        ) && message.contains("--without observation.images.wrist"),
        "{message}"
    );
}

/// Through the CLI: a LeRobot dataset without our metadata (so its depth TIFF is another
/// tool's float image, not necessarily metres) goes to RLDS as a float32 tensor of its shape,
/// every value kept; `--without` leaves it out by its key.
#[test]
fn a_foreign_float_image_becomes_an_rlds_float_tensor() {
    let parent = temp_root("hostile-tiff-cli");
    sentinel(&parent);
    let dataset = parent.join("foreign");
    let text = dataset.to_str().expect("utf-8");
    collect(text, "1", &[]);
    for ours in ["meta/surgvla.json", "meta/surgvla_manifest.json"] {
        std::fs::remove_file(dataset.join(ours)).expect("remove");
    }
    let out = parent.join("out");
    let out_text = out.to_str().expect("utf-8");
    let tensor = parent.join("tensor");
    let tensor_text = tensor.to_str().expect("utf-8");
    let args = ["convert", text, "--to", "rlds", "--out", tensor_text];
    expect_exit(&parent, &args, 0, "float TIFF to RLDS");
    let (code, report) = run(&["validate", tensor_text, "--no-lint"], LIMIT);
    assert_eq!(code, 0, "{report}");
    let features: serde_json::Value = serde_json::from_slice(
        &std::fs::read(tensor.join("surgvla_benchmark/1.0.0/features.json")).expect("features"),
    )
    .expect("json");
    let observation = &features["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"]
        ["features"]["observation"]["featuresDict"]["features"];
    let depth = &observation["depth"]["tensor"];
    assert_eq!(depth["dtype"], "float32", "{observation}");
    assert_eq!(
        depth["shape"]["dimensions"],
        serde_json::json!(["224", "224", "1"])
    );
    // The way past: leave the feature out by its key (another tool's, not surgvla's `depth`).
    let args = [
        "convert",
        text,
        "--to",
        "rlds",
        "--without",
        "observation.images.depth",
        "--out",
        out_text,
    ];
    expect_exit(&parent, &args, 0, "without the float image");
    let (code, report) = run(&["validate", out_text, "--no-lint"], LIMIT);
    assert_eq!(code, 0, "{report}");
    let features = std::fs::read_to_string(out.join("surgvla_benchmark/1.0.0/features.json"))
        .expect("features.json");
    assert!(!features.contains("depth"), "the feature is left out");
    // A key the input lacks is refused before anything is written, naming the keys it has.
    let refused = parent.join("refused");
    let refused = refused.to_str().expect("utf-8");
    let args = [
        "convert",
        text,
        "--to",
        "rlds",
        "--without",
        "observation.images.nothing",
        "--out",
        refused,
    ];
    let stderr = expect_exit(&parent, &args, 2, "an unknown key");
    assert!(
        stderr.contains("has no such feature") && stderr.contains("observation.state"),
        "{stderr}"
    );
    assert!(!parent.join("refused").exists());
}

/// A special file where a dataset has a regular one.
#[derive(Clone, Copy, Debug)]
enum Special {
    /// Opening it for reading waits for a writer for ever.
    Fifo,
    Directory,
    /// A link to itself: opening it fails with "too many levels of symbolic links".
    LinkLoop,
}

fn make_special(path: &Path, kind: Special) {
    std::fs::remove_file(path).expect("remove");
    match kind {
        Special::Fifo => {
            let made = std::process::Command::new("mkfifo")
                .arg(path)
                .status()
                .expect("mkfifo");
            assert!(made.success(), "mkfifo {}", path.display());
        }
        Special::Directory => std::fs::create_dir(path).expect("dir"),
        Special::LinkLoop => std::os::unix::fs::symlink(path, path).expect("link"),
    }
}

/// FIFOs, folders and link loops in place of a dataset's files (its metadata, a data parquet, a
/// video, a zarr chunk, an RLDS shard) are refused without being opened: every command reading
/// the dataset ends within 20 s without a crash (the FIFO was a hang: opened before its type was
/// checked), `validate` with exit 1, and nothing outside the dataset and the output changes.
#[test]
fn special_files_are_refused_before_they_are_opened() {
    let limit = Duration::from_secs(20);
    let parent = temp_root("hostile-special");
    sentinel(&parent);
    let formats: [(&str, &[&str], &[&str]); 3] = [
        (
            "lerobot",
            &["--video", "h264"],
            &["meta/info.json", "meta/stats.json", ".parquet", ".mp4"],
        ),
        (
            "rlds",
            &["--format", "rlds"],
            &["features.json", ".tfrecord-"],
        ),
        ("zarr", &["--format", "zarr"], &[".zarray", "/0.0"]),
    ];
    for (name, extra, targets) in formats {
        let base = parent.join(format!("base-{name}"));
        collect(base.to_str().expect("utf-8"), "1", extra);
        let files = files_where(&base, |_| true);
        for (i, target) in targets.iter().enumerate() {
            let file = files
                .iter()
                .find(|f| f.contains(target))
                .unwrap_or_else(|| panic!("{name}: no {target} in {files:?}"));
            for kind in [Special::Fifo, Special::Directory, Special::LinkLoop] {
                let dataset = parent.join(format!("{name}-{i}-{kind:?}"));
                copy_tree(&base, &dataset);
                make_special(&dataset.join(file), kind);
                let text = dataset.to_str().expect("utf-8").to_string();
                let out = format!("{text}-out");
                let merged = format!("{text}-merged");
                let base_text = base.to_str().expect("utf-8");
                let what = format!("{name}: {file} as {kind:?}");
                for command in [
                    vec!["validate", text.as_str()],
                    vec!["info", text.as_str()],
                    vec!["convert", &text, "--to", "lerobot", "--out", &out],
                    vec!["merge", base_text, &text, "--out", &merged],
                ] {
                    let before = tree(&parent.join("outside"));
                    let (code, stderr) = run(&command, limit);
                    // Converting and merging may go on without a file they can rebuild
                    // (stats.json): exit 0 is allowed there, a hang or a crash never.
                    let expected: &[i32] = if command[0] == "validate" {
                        &[1]
                    } else {
                        &[0, 1, 2]
                    };
                    assert!(
                        expected.contains(&code),
                        "{what}: {command:?} exit {code}: {stderr}"
                    );
                    assert!(!stderr.contains("panicked"), "{what}: {stderr}");
                    assert_eq!(tree(&parent.join("outside")), before, "{what}");
                }
            }
        }
    }
}

/// The compact-thrift varint of the zigzag of `value`.
fn zigzag_varint(value: i64) -> Vec<u8> {
    let mut n = ((value << 1) ^ (value >> 63)) as u64;
    let mut out = Vec::new();
    loop {
        let byte = (n & 0x7f) as u8;
        n >>= 7;
        if n == 0 {
            out.push(byte);
            return out;
        }
        out.push(byte | 0x80);
    }
}

/// A data file's footer rewritten so that its row count is a lie, in the file's own count (the
/// footer's bytes patched) or a row group's: every command gives the same verdict (exit 1
/// naming the file), none reads rows.
#[test]
fn a_forged_parquet_row_count_gets_one_verdict_from_every_command() {
    use parquet::file::metadata::{ParquetMetaData, ParquetMetaDataWriter};
    let parent = temp_root("hostile-rows");
    sentinel(&parent);
    let base = parent.join("base");
    collect(base.to_str().expect("utf-8"), "2", &["--shard", "0/2"]);
    let second = parent.join("second");
    let second = second.to_str().expect("utf-8");
    collect(second, "2", &["--shard", "1/2"]);
    let data = "data/chunk-000/file-000.parquet";
    let original = std::fs::read(base.join(data)).expect("data");
    let metadata = surgvla::export::lerobot::read::open_parquet(&base.join(data))
        .expect("footer")
        .metadata()
        .as_ref()
        .clone();
    let length = u32::from_le_bytes(original[original.len() - 8..][..4].try_into().expect("4"));
    let body = &original[..original.len() - 8 - length as usize];
    let footer = &original[body.len()..original.len() - 8];
    // FileMetaData's field 3 (i64, the field after the schema list): header 0x16, then the count.
    let true_rows = [
        &[0x16][..],
        &zigzag_varint(metadata.file_metadata().num_rows()),
    ]
    .concat();
    let at = footer
        .windows(true_rows.len())
        .position(|w| w == true_rows)
        .expect("the file's row count");
    let cases = [
        ("file", 1_000_000_000_000i64),
        ("file", -1),
        ("file", i64::MAX),
        ("group", 1_000_000_000_000),
    ];
    for (level, rows) in cases {
        let mut bytes = body.to_vec();
        if level == "file" {
            let mut forged = footer[..at].to_vec();
            forged.push(0x16);
            forged.extend(zigzag_varint(rows));
            forged.extend_from_slice(&footer[at + true_rows.len()..]);
            bytes.extend_from_slice(&forged);
            bytes.extend_from_slice(&(forged.len() as u32).to_le_bytes());
            bytes.extend_from_slice(b"PAR1");
        } else {
            let group = metadata.row_group(0).clone().into_builder();
            let group = group.set_num_rows(rows).build().expect("group");
            let forged = ParquetMetaData::new(metadata.file_metadata().clone(), vec![group]);
            ParquetMetaDataWriter::new(&mut bytes, &forged)
                .finish()
                .expect("footer");
        }
        let dataset = parent.join(format!("forged-{level}-{rows}"));
        copy_tree(&base, &dataset);
        std::fs::write(dataset.join(data), bytes).expect("forge");
        std::fs::remove_file(dataset.join("meta/surgvla_manifest.json")).expect("manifest");
        let input = dataset.to_str().expect("utf-8");
        let out = parent.join("out");
        let out = out.to_str().expect("utf-8");
        for args in [
            vec!["validate", input],
            vec!["validate", input, "--quick"],
            vec!["info", input],
            vec!["convert", input, "--to", "rlds", "--out", out],
            vec!["merge", input, second, "--out", out],
            vec![
                "eval",
                "--policy",
                "replay",
                "--dataset",
                input,
                "--tasks",
                "T1-1",
                "--trials",
                "1",
                "--out",
                out,
            ],
        ] {
            let what = format!("{level} rows {rows}");
            let text = expect_exit(&parent, &args, 1, &what);
            assert!(
                text.contains("file-000.parquet") && text.contains(&format!("claims {rows} rows")),
                "{what} {args:?}: {text}"
            );
            std::fs::remove_dir_all(parent.join("out")).ok();
        }
    }
}

/// A zarr array whose chunk keys would be joined by anything but `.` or `/` (a path out of the
/// store), or whose chunks pass through filters surgvla does not apply, is not called valid;
/// nested (`/`) chunk keys, which zarr allows, are read.
#[test]
fn zarr_separators_and_filters_are_checked_not_trusted() {
    let parent = temp_root("hostile-zarr");
    sentinel(&parent);
    let base = parent.join("base");
    collect(base.to_str().expect("utf-8"), "1", &["--format", "zarr"]);
    std::fs::remove_file(base.join("surgvla_manifest.json")).expect("no manifest");
    let array = "data/state";
    let cases: [(&str, Value, &str); 3] = [
        (
            "dimension_separator",
            Value::from("/../../../"),
            "is not '.' or '/'",
        ),
        (
            "filters",
            serde_json::json!([{"id": "delta", "dtype": "<f4"}]),
            "not applied",
        ),
        ("dimension_separator", Value::from("/"), ""),
    ];
    for (key, value, problem) in cases {
        let dataset = parent.join(format!("zarr-{key}-{}", problem.len()));
        copy_tree(&base, &dataset);
        edit_json(&dataset.join(array).join(".zarray"), |meta| {
            meta[key] = value.clone();
        });
        let input = dataset.to_str().expect("utf-8");
        if problem.is_empty() {
            // Nested keys: chunk 0.0 lives at 0/0.
            let folder = dataset.join(array);
            for entry in std::fs::read_dir(&folder).expect("chunks") {
                let name = entry
                    .expect("entry")
                    .file_name()
                    .into_string()
                    .expect("name");
                if let Some((row, column)) = name.split_once('.')
                    && row.parse::<u64>().is_ok()
                {
                    std::fs::create_dir_all(folder.join(row)).expect("mkdir");
                    std::fs::rename(folder.join(&name), folder.join(row).join(column))
                        .expect("nest");
                }
            }
            expect_exit(&parent, &["validate", input], 0, "nested keys");
            continue;
        }
        for args in [vec!["validate", input], vec!["validate", input, "--quick"]] {
            let text = expect_exit(&parent, &args, 1, key);
            assert!(text.contains(".zarray") && text.contains(problem), "{text}");
        }
        let out = parent.join("merged");
        let out = out.to_str().expect("utf-8");
        let text = expect_exit(&parent, &["merge", input, input, "--out", out], 1, key);
        assert!(text.contains(".zarray"), "{text}");
    }
}

/// Seeded mutations of the recordings `ingest` reads (a ROS 1 bag with LZ4 chunks, an MCAP
/// file with PNG images): every run ends within the limits with exit 0, 1 or 2, and the output
/// is either a finished dataset that validates or no dataset that looks finished.
#[test]
fn mutated_recordings_never_panic_hang_or_escape() {
    let parent = temp_root("hostile-ingest");
    sentinel(&parent);
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ingest");
    let mut rng = surgvla::rng::SplitMix64::new(5);
    for name in ["ros1_raw_lz4.bag", "single_png.mcap"] {
        let original = std::fs::read(fixtures.join(name)).expect("fixture");
        for round in 0..16 {
            let Some((bytes, how)) = mutate_bytes(&original, &mut rng) else {
                continue;
            };
            let input = parent.join(format!("{round}-{name}"));
            std::fs::write(&input, bytes).expect("write");
            let out = parent.join(format!("out-{round}-{name}"));
            let (input_text, out_text) =
                (input.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
            let what = format!("{name} round {round}: {how}");
            let before = tree(&parent.join("outside"));
            let args = [
                "ingest",
                input_text,
                "--camera",
                "left=/camera/left/image",
                "--out",
                out_text,
            ];
            let (code, stderr) = run(&args, LIMIT);
            assert!((0..=2).contains(&code), "{what}: exit {code}: {stderr}");
            assert!(!stderr.contains("panicked"), "{what}: {stderr}");
            assert_eq!(
                tree(&parent.join("outside")),
                before,
                "{what}: the sentinel changed"
            );
            let finished = out.exists() && !out.join(surgvla::export::INCOMPLETE_MARKER).exists();
            if code == 0 {
                let (valid, text) = run(&["validate", out_text, "--no-lint"], LIMIT);
                assert_eq!(valid, 0, "{what}: ingest exit 0, validate: {text}");
            } else {
                assert!(
                    !finished,
                    "{what}: exit {code} left a finished-looking dataset"
                );
            }
        }
    }
}
