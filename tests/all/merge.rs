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
