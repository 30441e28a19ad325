//! `surgvla merge`: N shards of one collection merged equal the single-machine run byte for
//! byte (all but the report's timings), for N = 1, 2, 3 and in any argument order; the merged
//! dataset validates; incompatible inputs and the same shard twice are refused with exit 2.

use crate::util::{kill_after_checkpoint, surgvla, temp_root, tree};
use std::path::Path;

const SMALL: [&str; 4] = ["--tasks", "T1-1,T3-1", "--episodes-per-task", "2"];

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn collect(out: &Path, extra: &[&str]) {
    let mut args = vec!["collect", "--out", path(out)];
    args.extend(SMALL);
    args.extend(extra);
    let (code, _, err) = surgvla(&args);
    assert_eq!(code, 0, "{args:?}: {err}");
}

/// Every file but the report, whose timings differ.
fn dataset(root: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut files = tree(root);
    files.remove("collect_report.json");
    files
}

#[test]
fn merged_shards_equal_the_single_machine_run() {
    let single = temp_root("merge-single");
    collect(&single, &[]);
    let expected = dataset(&single);
    for n in 1..=3u32 {
        let shards: Vec<_> = (0..n)
            .map(|i| {
                let shard = temp_root("merge-shard");
                collect(&shard, &["--shard", &format!("{i}/{n}")]);
                shard
            })
            .collect();
        let out = temp_root("merge-out");
        // Shards given in reverse: merge puts them in shard order.
        let mut args = vec!["merge"];
        args.extend(shards.iter().rev().map(|s| path(s)));
        args.extend(["--out", path(&out)]);
        let (code, stdout, err) = surgvla(&args);
        assert_eq!(code, 0, "N = {n}: {err}");
        assert!(stdout.contains("4 episodes"), "{stdout}");
        let merged = dataset(&out);
        assert_eq!(
            merged.keys().collect::<Vec<_>>(),
            expected.keys().collect::<Vec<_>>(),
            "N = {n}"
        );
        for (name, bytes) in &expected {
            assert!(merged[name] == *bytes, "N = {n}: {name} differs");
        }
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join("collect_report.json")).expect("report"),
        )
        .expect("json");
        assert_eq!(report["episodes"], 4);
        assert_eq!(report["merged_from"], n);
        let (code, _, err) = surgvla(&["validate", path(&out)]);
        assert_eq!(code, 0, "{err}");
    }
}

#[test]
fn incompatible_inputs_are_refused() {
    let a = temp_root("merge-a");
    collect(&a, &["--shard", "0/2"]);
    let other_seed = temp_root("merge-seed");
    collect(&other_seed, &["--shard", "1/2", "--seed", "9"]);
    let v21 = temp_root("merge-v21");
    collect(&v21, &["--shard", "1/2", "--lerobot-version", "2.1"]);
    for (other, said) in [
        (&other_seed, "collection option seed"),
        (&v21, "layout"),
        (&a, "both are shard"),
    ] {
        let out = temp_root("merge-refused");
        let (code, _, err) = surgvla(&["merge", path(&a), path(other), "--out", path(&out)]);
        assert_eq!(code, 2, "{said}: {err}");
        assert!(err.contains(said), "{said}: {err}");
        assert!(!out.exists(), "{said}: nothing written");
    }
    let out = temp_root("merge-missing");
    let (code, _, err) = surgvla(&["merge", path(&a), "/nonexistent/x", "--out", path(&out)]);
    assert_eq!(code, 2, "{err}");
}

/// A killed merge is not a dead end: the re-run says to add `--resume`, which continues it to
/// the bytes of an uninterrupted merge; other inputs are refused.
#[test]
fn a_killed_merge_resumes_to_the_uninterrupted_dataset() {
    let parent = temp_root("merge-killed");
    let shard = |i: usize| parent.join(format!("shard-{i}"));
    for i in 0..2 {
        let out = shard(i);
        let (code, _, stderr) = surgvla(&[
            "collect",
            "--tasks",
            "T1-1",
            "--episodes-per-task",
            "8",
            "--shard",
            &format!("{i}/2"),
            "--data-file-mb",
            "1",
            "--out",
            out.to_str().expect("utf-8"),
        ]);
        assert_eq!(code, 0, "{stderr}");
    }
    let (a, b) = (shard(0), shard(1));
    let (a, b) = (a.to_str().expect("utf-8"), b.to_str().expect("utf-8"));
    let reference = parent.join("reference");
    let (code, _, stderr) = surgvla(&["merge", a, b, "--out", reference.to_str().expect("utf-8")]);
    assert_eq!(code, 0, "{stderr}");

    let killed = parent.join("killed");
    let killed_text = killed.to_str().expect("utf-8");
    kill_after_checkpoint(
        &["merge", a, b, "--out", killed_text, "--threads", "1"],
        &killed,
    );

    let (code, _, stderr) = surgvla(&["merge", a, b, "--out", killed_text]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("--resume"), "{stderr}");
    let (code, _, stderr) = surgvla(&["merge", b, a, "--out", killed_text, "--resume"]);
    assert_eq!(
        code, 0,
        "shards are put in shard order whatever the order given: {stderr}"
    );
    let files = |root: &Path| {
        let mut files = tree(root);
        files.remove("collect_report.json");
        files
    };
    assert!(files(&killed) == files(&reference), "resumed merge differs");
}

/// The converted dataset's files, every one (conversions write no report).
fn converted(input: &Path, to: &[&str], shard: Option<&str>) -> crate::util::TempRoot {
    let out = temp_root("merge-converted");
    let mut args = vec!["convert", path(input), "--out", path(&out)];
    args.extend(to);
    if let Some(shard) = shard {
        args.extend(["--shard", shard]);
    }
    let (code, _, err) = surgvla(&args);
    assert_eq!(code, 0, "{args:?}: {err}");
    out
}

/// `convert --shard I/N` into each format that has a dataset folder, merged (shards given in
/// reverse): the single conversion's bytes, every file.
#[test]
fn converted_shards_of_every_format_merge_into_the_single_conversion() {
    let input = temp_root("merge-convert-input");
    collect(&input, &[]);
    let targets: [&[&str]; 6] = [
        &["--to", "rlds", "--rlds-shard-mb", "1"],
        &["--to", "zarr", "--zarr-images"],
        &["--to", "ply"],
        &["--to", "pcd"],
        &["--to", "mcap"],
        &["--to", "lerobot"],
    ];
    for to in targets {
        let single = converted(&input, to, None);
        let expected = tree(&single);
        for n in [2u32, 3] {
            let shards: Vec<_> = (0..n)
                .map(|i| converted(&input, to, Some(&format!("{i}/{n}"))))
                .collect();
            let out = temp_root("merge-converted-out");
            let mut args = vec!["merge"];
            args.extend(shards.iter().rev().map(|s| path(s)));
            args.extend(["--out", path(&out)]);
            let (code, stdout, err) = surgvla(&args);
            assert_eq!(code, 0, "{to:?} N = {n}: {err}");
            assert!(stdout.contains("4 episodes"), "{stdout}");
            let merged = tree(&out);
            assert_eq!(
                merged.keys().collect::<Vec<_>>(),
                expected.keys().collect::<Vec<_>>(),
                "{to:?} N = {n}"
            );
            for (name, bytes) in &expected {
                assert!(merged[name] == *bytes, "{to:?} N = {n}: {name} differs");
            }
            let (code, _, err) = surgvla(&["validate", path(&out)]);
            assert_eq!(code, 0, "{to:?}: {err}");
        }
    }
}

/// Collected shards in RLDS and zarr merge into the single run, the report merged beside.
#[test]
fn collected_rlds_and_zarr_shards_merge_into_the_single_run() {
    for format in [&["--format", "rlds"][..], &["--format", "zarr"][..]] {
        let single = temp_root("merge-collect-single");
        collect(&single, format);
        let shards: Vec<_> = (0..2)
            .map(|i| {
                let shard = temp_root("merge-collect-shard");
                let mut extra = format.to_vec();
                let label = format!("{i}/2");
                extra.extend(["--shard", &label]);
                collect(&shard, &extra);
                shard
            })
            .collect();
        let out = temp_root("merge-collect-out");
        let (code, _, err) = surgvla(&[
            "merge",
            path(&shards[1]),
            path(&shards[0]),
            "--out",
            path(&out),
        ]);
        assert_eq!(code, 0, "{format:?}: {err}");
        assert!(
            dataset(&out) == dataset(&single),
            "{format:?}: merged differs"
        );
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join("collect_report.json")).expect("report"),
        )
        .expect("json");
        assert_eq!(report["episodes"], 4, "{format:?}");
        assert_eq!(report["shard"], "0/1", "{format:?}");
    }
}

/// Shards that differ in an option that shapes the bytes are refused naming it, as is a
/// dataset whose manifest records no options, a shard past the input's episodes and the
/// sharding of a shard; nothing is written.
#[test]
fn merging_other_formats_refuses_what_cannot_make_one_run() {
    let input = temp_root("merge-refuse-input");
    collect(&input, &[]);
    let a = converted(&input, &["--to", "zarr"], Some("0/2"));
    let b = converted(&input, &["--to", "zarr", "--points", "512"], Some("1/2"));
    let out = temp_root("merge-refuse-out");
    let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&out)]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("cloud_points"), "{err}");
    assert!(!out.exists());

    let old = converted(&input, &["--to", "ply"], Some("1/2"));
    let manifest = old.join("surgvla_manifest.json");
    let mut value: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest).expect("manifest")).expect("json");
    value.as_object_mut().expect("object").remove("options");
    std::fs::write(&manifest, serde_json::to_vec_pretty(&value).expect("json")).expect("write");
    let first = converted(&input, &["--to", "ply"], Some("0/2"));
    let (code, _, err) = surgvla(&["merge", path(&first), path(&old), "--out", path(&out)]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("records no options"), "{err}");
    assert!(!out.exists());

    let (code, _, err) = surgvla(&[
        "convert",
        path(&input),
        "--to",
        "rlds",
        "--shard",
        "0/5",
        "--out",
        path(&out),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("would hold no episode"), "{err}");
    assert!(!out.exists());
    let shard = converted(&input, &["--to", "rlds"], Some("0/2"));
    let (code, _, err) = surgvla(&[
        "convert",
        path(&shard),
        "--to",
        "zarr",
        "--shard",
        "0/2",
        "--out",
        path(&out),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("itself shard 0/2"), "{err}");
    assert!(!out.exists());
}

/// A damaged chunk or frame file in an input fails the merge naming the file (exit 1), and the
/// output is left marked incomplete, never looking finished.
#[test]
fn a_damaged_input_file_fails_the_merge_naming_it() {
    let input = temp_root("merge-damaged-input");
    collect(&input, &[]);
    let cases = [
        ("zarr", "data/state/0.0"),
        ("pcd", "episode_000001/frame_000003.pcd"),
        ("mcap", "episode_000001.mcap"),
    ];
    for (to, damaged) in cases {
        let a = converted(&input, &["--to", to], Some("0/2"));
        let b = converted(&input, &["--to", to], Some("1/2"));
        let file = b.join(damaged);
        let bytes = std::fs::read(&file).expect("file");
        if to != "pcd" {
            std::fs::write(&file, &bytes[..bytes.len() / 2]).expect("truncate");
        } else {
            std::fs::remove_file(&file).expect("remove");
        }
        let out = temp_root("merge-damaged-out");
        let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&out)]);
        assert_ne!(code, 0, "{to}: {err}");
        assert!(err.contains(damaged), "{to}: {err}");
        let complete = out.exists() && !out.join(surgvla::export::INCOMPLETE_MARKER).exists();
        assert!(
            !complete || tree(&out).is_empty(),
            "{to}: the output looks complete"
        );
    }
}

/// Rewrites the first occurrence of `from` in the file at `path` with `to`.
fn forge(path: &Path, from: &str, to: &[u8]) {
    let bytes = std::fs::read(path).expect("frame");
    let at = bytes
        .windows(from.len())
        .position(|w| w == from.as_bytes())
        .expect("in the header");
    let mut forged = bytes[..at].to_vec();
    forged.extend_from_slice(to);
    forged.extend_from_slice(&bytes[at + from.len()..]);
    std::fs::write(path, forged).expect("forge");
}

/// A point-cloud frame plyfile or PCL could not read (a header declaring 10^12 points, one
/// that never ends, a compressed body declaring gigabytes) is found by validate, full and
/// quick, with or without the manifest, and never copied into a merged dataset.
#[test]
fn a_forged_point_cloud_is_never_called_valid_nor_merged() {
    let input = temp_root("merge-forged-cloud-input");
    collect(&input, &[]);
    let endless = [
        b"ply\nformat binary_little_endian 1.0\n".as_slice(),
        &[b' '; 1 << 17],
    ]
    .concat();
    let mut bomb = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n\
        WIDTH 200000000\nHEIGHT 1\nPOINTS 200000000\nDATA binary_compressed\n"
        .to_vec();
    bomb.extend_from_slice(&5u32.to_le_bytes());
    bomb.extend_from_slice(&2_400_000_000u32.to_le_bytes());
    bomb.extend_from_slice(&[0, 0, 0xE0, 14, 0]);
    type Forgery<'a> = (&'a str, &'a dyn Fn(&Path), &'a str);
    let cases: [Forgery<'_>; 3] = [
        (
            "ply",
            &|file| forge(file, "element vertex ", b"element vertex 99999999999"),
            "cannot hold",
        ),
        (
            "ply",
            &|file| std::fs::write(file, &endless).expect("forge"),
            "64 KiB",
        ),
        (
            "pcd",
            &|file| std::fs::write(file, &bomb).expect("forge"),
            "cannot hold",
        ),
    ];
    for (to, damage, problem) in cases {
        let a = converted(&input, &["--to", to], Some("0/2"));
        let b = converted(&input, &["--to", to], Some("1/2"));
        let damaged = format!("episode_000001/frame_000003.{to}");
        damage(&b.join(&damaged));
        let out = temp_root("merge-forged-cloud-out");
        let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&out)]);
        assert_eq!(code, 1, "{to}: {err}");
        assert!(err.contains(&damaged) && err.contains(problem), "{err}");
        let (code, ..) = surgvla(&["validate", path(&out)]);
        assert_ne!(code, 0, "{to}: the merged output is called valid");
        std::fs::remove_file(b.join("surgvla_manifest.json")).expect("no manifest");
        for quick in [&[][..], &["--quick"]] {
            let mut args = vec!["validate", path(&b)];
            args.extend(quick);
            let (code, out, err) = surgvla(&args);
            assert_eq!(code, 1, "{to} {quick:?}: {out}{err}");
            assert!(out.contains(&damaged) && out.contains(problem), "{out}");
        }
    }
}

/// A zarr, MCAP, PLY or PCD merge stopped part-way (an input file found damaged after the
/// first input's episodes were written) leaves its folder marked interrupted; with the file
/// repaired, `merge --resume` finishes it with the bytes of an uninterrupted merge, as the
/// failure's hint says.
#[test]
fn an_interrupted_copy_merge_resumes_to_the_uninterrupted_bytes() {
    let input = temp_root("merge-resume-copy-input");
    collect(&input, &[]);
    let cases = [
        ("zarr", "data/state/0.0"),
        ("mcap", "episode_000001.mcap"),
        ("ply", "episode_000001/frame_000003.ply"),
        ("pcd", "episode_000001/frame_000003.pcd"),
    ];
    for (to, damaged) in cases {
        let a = converted(&input, &["--to", to], Some("0/2"));
        let b = converted(&input, &["--to", to], Some("1/2"));
        let reference = temp_root("merge-resume-copy-reference");
        let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&reference)]);
        assert_eq!(code, 0, "{to}: {err}");
        let file = b.join(damaged);
        let bytes = std::fs::read(&file).expect("file");
        std::fs::write(&file, &bytes[..bytes.len() / 2]).expect("truncate");
        let out = temp_root("merge-resume-copy-out");
        let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&out)]);
        assert_eq!(code, 1, "{to}: {err}");
        assert!(
            out.join(surgvla::export::INCOMPLETE_MARKER).exists(),
            "{to}: the stopped merge's folder is marked interrupted"
        );
        std::fs::write(&file, &bytes).expect("repair");
        let args = ["merge", path(&a), path(&b), "--out", path(&out), "--resume"];
        let (code, _, err) = surgvla(&args);
        assert_eq!(code, 0, "{to}: {err}");
        assert_eq!(dataset(&out), dataset(&reference), "{to}: resumed bytes");
    }
}

/// An RLDS merge killed after a closed shard resumes to the bytes of an uninterrupted one.
#[test]
fn a_killed_rlds_merge_resumes_to_the_uninterrupted_dataset() {
    let parent = temp_root("merge-rlds-killed");
    let shard = |i: usize| parent.join(format!("shard-{i}"));
    for i in 0..2 {
        let label = format!("{i}/2");
        let out = shard(i);
        let args = [
            "collect",
            "--tasks",
            "T1-1",
            "--episodes-per-task",
            "8",
            "--format",
            "rlds",
            "--rlds-shard-mb",
            "1",
            "--shard",
            &label,
            "--out",
            path(&out),
        ];
        let (code, _, err) = surgvla(&args);
        assert_eq!(code, 0, "{err}");
    }
    let (a, b) = (shard(0), shard(1));
    let reference = parent.join("reference");
    let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&reference)]);
    assert_eq!(code, 0, "{err}");
    let killed = parent.join("killed");
    kill_after_checkpoint(
        &[
            "merge",
            path(&a),
            path(&b),
            "--out",
            path(&killed),
            "--threads",
            "1",
        ],
        &killed,
    );
    let (code, _, err) = surgvla(&["merge", path(&a), path(&b), "--out", path(&killed)]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--resume"), "{err}");
    let (code, _, err) = surgvla(&[
        "merge",
        path(&b),
        path(&a),
        "--out",
        path(&killed),
        "--resume",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        dataset(&killed) == dataset(&reference),
        "resumed merge differs"
    );
}

/// A killed `convert --shard` resumes only as the same shard, to the uninterrupted shard's bytes.
#[test]
fn a_killed_converted_shard_resumes_only_as_itself() {
    let parent = temp_root("merge-convert-killed");
    let input = parent.join("input");
    let (code, _, err) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "8",
        "--out",
        path(&input),
    ]);
    assert_eq!(code, 0, "{err}");
    let args = |out: &Path, shard: &str| -> Vec<String> {
        let mut args = vec![
            "convert",
            path(&input),
            "--to",
            "rlds",
            "--rlds-shard-mb",
            "1",
        ];
        args.extend(["--shard", shard, "--out", path(out)]);
        args.into_iter().map(String::from).collect()
    };
    let convert = |out: &Path, shard: &str, extra: &[&str]| {
        let mut all = args(out, shard);
        all.extend(extra.iter().map(|e| e.to_string()));
        surgvla(&all.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let reference = parent.join("reference");
    let (code, _, err) = convert(&reference, "1/2", &[]);
    assert_eq!(code, 0, "{err}");
    let killed = parent.join("killed");
    let mut killed_args = args(&killed, "1/2");
    killed_args.extend(["--threads".to_string(), "1".to_string()]);
    kill_after_checkpoint(
        &killed_args.iter().map(String::as_str).collect::<Vec<_>>(),
        &killed,
    );
    let (code, _, err) = convert(&killed, "0/2", &["--resume"]);
    assert_eq!(code, 2, "another shard is another run: {err}");
    assert!(err.contains("shard"), "{err}");
    let (code, _, err) = convert(&killed, "1/2", &["--resume"]);
    assert_eq!(code, 0, "{err}");
    assert!(tree(&killed) == tree(&reference), "resumed shard differs");
}
