//! The format registry: every command sees one format per input. `validate` and `convert`
//! agree on every input (an unrecognised one exits 2 in both; a recognised format `convert`
//! does not read exits 2 naming it), `merge` refuses formats it does not merge, a dataset that
//! only looks like a format is a finding for `validate` and a failure for `convert`, and a
//! folder of point-cloud files is validated like every other output.

use crate::util::{surgvla, temp_root};
use std::path::Path;
use surgvla::export::{BUILTIN_FORMATS, registry};

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

/// `validate --json`'s format, or None when it cannot run (exit 2).
fn validated_format(input: &Path) -> Option<String> {
    let (code, stdout, stderr) = surgvla(&["validate", path(input), "--json", "--quick"]);
    if code == 2 {
        return None;
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("a JSON report");
    Some(report["format"].as_str().expect("a format").to_string())
}

/// One T1-1 episode collected into `out` (with `extra` options).
fn collect_one(out: &Path, extra: &[&str]) {
    let mut args = vec!["collect", "--tasks", "T1-1", "--episodes-per-task", "1"];
    args.extend(extra);
    args.extend(["--out", path(out)]);
    let (code, _, stderr) = surgvla(&args);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn validate_and_convert_agree_on_every_input() {
    let root = temp_root("registry");
    let lerobot = root.join("lerobot");
    collect_one(&lerobot, &[]);
    let mut inputs = vec![(lerobot.clone(), Some("lerobot-v3.0"))];
    for (to, format) in [
        ("rlds", "rlds"),
        ("zarr", "zarr"),
        ("mcap", "mcap"),
        ("ply", "ply"),
        ("pcd", "pcd"),
    ] {
        let out = root.join(to);
        let (code, _, stderr) =
            surgvla(&["convert", path(&lerobot), "--to", to, "--out", path(&out)]);
        assert_eq!(code, 0, "{to}: {stderr}");
        inputs.push((out, Some(format)));
    }
    let empty = root.join("empty");
    std::fs::create_dir_all(&empty).expect("empty");
    let text = root.join("notes.txt");
    std::fs::write(&text, "not a dataset").expect("text");
    inputs.push((empty, None));
    inputs.push((text, None));
    inputs.push((root.join("missing"), None));
    for (input, expected) in inputs {
        let format = validated_format(&input);
        assert_eq!(format.as_deref(), expected, "{}", input.display());
        let out = root.join("converted");
        let (code, _, stderr) = surgvla(&[
            "convert",
            path(&input),
            "--to",
            "lerobot",
            "--out",
            path(&out),
        ]);
        std::fs::remove_dir_all(&out).ok();
        assert!(!stderr.contains("panicked"), "{stderr}");
        match format.as_deref() {
            None => assert_eq!(code, 2, "{}: {stderr}", input.display()),
            Some("lerobot-v3.0" | "rlds") => assert_eq!(code, 0, "{}: {stderr}", input.display()),
            Some(name) => {
                assert_eq!(code, 2, "{}: {stderr}", input.display());
                assert!(
                    stderr.contains(&format!("does not read {name}")),
                    "{stderr}"
                );
            }
        }
    }
    // merge joins every format, one format at a time (and the same run once).
    let (code, _, stderr) = surgvla(&[
        "merge",
        path(&root.join("rlds")),
        path(&root.join("rlds")),
        "--out",
        path(&root.join("merged")),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("both are shard \"0/1\""), "{stderr}");
    let (code, _, stderr) = surgvla(&[
        "merge",
        path(&lerobot),
        path(&root.join("zarr")),
        "--out",
        path(&root.join("merged")),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("it is zarr, the first is lerobot"),
        "{stderr}"
    );
    assert!(!root.join("merged").exists());
}

#[test]
fn a_broken_dataset_is_a_finding_for_validate_and_a_failure_for_convert() {
    let root = temp_root("registry-broken");
    let lerobot = root.join("lerobot");
    collect_one(&lerobot, &[]);
    std::fs::remove_file(lerobot.join("meta/info.json")).expect("remove info.json");
    let (code, stdout, _) = surgvla(&["validate", path(&lerobot)]);
    assert_eq!(code, 1, "{stdout}");
    let (code, _, stderr) = surgvla(&[
        "convert",
        path(&lerobot),
        "--to",
        "rlds",
        "--out",
        path(&root.join("out")),
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("no meta/info.json"), "{stderr}");
}

#[test]
fn point_cloud_folders_are_validated_and_their_defects_named() {
    let root = temp_root("registry-ply");
    let ply = root.join("ply");
    collect_one(&ply, &["--format", "ply"]);
    let (code, stdout, stderr) = surgvla(&["validate", path(&ply), "--json"]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
    assert_eq!(report["format"], "ply");
    assert_eq!(report["episodes"], 1);
    let frames = report["frames"].as_u64().expect("frames");
    assert!(frames > 10, "{report}");
    // One frame file gone: the manifest and the frame count both say so.
    std::fs::remove_file(ply.join("episode_000000/frame_000003.ply")).expect("remove");
    let (code, stdout, _) = surgvla(&["validate", path(&ply), "--json"]);
    assert_eq!(code, 1, "{stdout}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
    let checks: Vec<&str> = report["errors"]
        .as_array()
        .expect("errors")
        .iter()
        .filter_map(|e| e["check"].as_str())
        .collect();
    assert!(checks.contains(&"frames"), "{report}");
    assert!(checks.contains(&"checksum"), "{report}");
    assert_eq!(report["frames"].as_u64(), Some(frames - 1));
}

#[test]
fn every_format_is_listed_once_and_says_what_it_does() {
    let names: std::collections::BTreeSet<&str> =
        BUILTIN_FORMATS.iter().map(|f| f.name()).collect();
    assert_eq!(names.len(), BUILTIN_FORMATS.len(), "{names:?}");
    let mut layouts = std::collections::BTreeSet::new();
    for format in BUILTIN_FORMATS {
        assert_eq!(registry::by_name(format.name()), Some(*format));
        assert!(!format.title().is_empty() && !format.help().is_empty());
        assert!(!format.layouts().is_empty(), "{format:?}");
        for layout in format.layouts() {
            assert!(layouts.insert(*layout), "{layout} is two formats' layout");
            assert_eq!(registry::of_layout(layout), Some(*format));
        }
        assert_eq!(
            format.schema_help().is_some(),
            format.schema(&crate::util::info(false)).is_some(),
            "{format:?}"
        );
    }
    // Messages list the formats from the registry.
    assert_eq!(registry::titles(|c| c.reads, "and"), "LeRobot and RLDS");
    assert_eq!(
        registry::titles(|c| c.point_clouds, "or"),
        "PLY, PCD, zarr or MCAP"
    );
}

#[test]
fn sniffing_reads_no_oversized_metadata() {
    // A point-cloud folder's surgvla.json over 1 MiB is not read to recognise it.
    let root = temp_root("registry-big");
    std::fs::create_dir_all(&*root).expect("root");
    let padding = " ".repeat(2 << 20);
    std::fs::write(
        root.join("surgvla.json"),
        format!(r#"{{"point_cloud": {{"file_format": "ply"}}}}{padding}"#),
    )
    .expect("surgvla.json");
    std::fs::write(root.join("episodes.jsonl"), "").expect("episodes");
    assert_eq!(validated_format(&root), None);
    std::fs::write(
        root.join("surgvla.json"),
        r#"{"point_cloud": {"file_format": "ply"}}"#,
    )
    .expect("surgvla.json");
    assert_eq!(validated_format(&root).as_deref(), Some("ply"));
}
