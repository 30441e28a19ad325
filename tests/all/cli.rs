//! The `surgvla` binary: user mistakes exit 2 with a clear message, runs print the trajectory.

use crate::util::{surgvla, temp_root};

#[test]
fn sim_runs_the_expert_through_grasp_release_and_a_verdict() {
    let (code, stdout, stderr) = surgvla(&["sim", "--task", "pick_and_place", "--seed", "1"]);
    assert_eq!(code, 0, "{stderr}");
    let grasp = stdout.find("grasp").expect("a grasp event");
    let release = stdout.find("release").expect("a release event");
    assert!(grasp < release, "{stdout}");
    assert!(stdout.contains("trajectory digest"));
    assert!(
        stdout.contains("success: gauze placed on the block"),
        "{stdout}"
    );
    // Cut short, the same expert has not finished the task.
    let (_, stdout, _) = surgvla(&["sim", "--task", "T3-1", "--seed", "1", "--steps", "20"]);
    assert!(stdout.contains("failure: 'gauze' never placed"), "{stdout}");
}

#[test]
fn sim_output_is_reproducible_and_seed_dependent() {
    let run = |seed: &str| surgvla(&["sim", "--task", "T1-2", "--seed", seed]).1;
    assert_eq!(run("4"), run("4"));
    assert_ne!(run("4"), run("5"));
}

#[test]
fn unknown_task_exits_2_with_the_task_list() {
    let (code, stdout, stderr) = surgvla(&["sim", "--task", "gauze_pik"]);
    assert_eq!(code, 2);
    assert!(stdout.is_empty());
    assert!(
        stderr.contains("unknown task 'gauze_pik'") && stderr.contains("gauze_pick (T1-1)"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"));
}

#[test]
fn bad_numbers_exit_2() {
    for args in [
        ["sim", "--steps", "-3"],
        ["sim", "--steps", "0"],
        ["sim", "--seed", "abc"],
    ] {
        let (code, _, stderr) = surgvla(&args);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(stderr.starts_with("error:"), "{stderr}");
        assert!(!stderr.contains("panicked"));
    }
}

#[test]
fn help_and_version_exit_0() {
    assert_eq!(surgvla(&["--help"]).0, 0);
    assert_eq!(surgvla(&["--version"]).0, 0);
    assert_eq!(surgvla(&["tasks"]).0, 0);
}

/// `collect -h` groups its flags under headings (what the episodes are, the output, how the
/// run goes, then each format's own), in that order of appearance, none left ungrouped.
#[test]
fn collect_help_groups_its_flags_by_purpose_and_format() {
    let (code, out, err) = surgvla(&["collect", "-h"]);
    assert_eq!(code, 0, "{err}");
    let headings: Vec<&str> = (out.lines())
        .filter(|l| l.ends_with(':') && !l.starts_with(' '))
        .collect();
    assert_eq!(
        headings,
        [
            "Options:",
            "Episodes:",
            "Running:",
            "Output:",
            "LeRobot:",
            "RLDS:",
            "Point clouds and zarr:"
        ],
        "{out}"
    );
    // Only --help is left under the generic "Options:".
    let options = out.split("Options:\n").nth(1).expect("options");
    let first_group = options.split("\n\n").next().expect("group");
    assert_eq!(
        first_group.trim(),
        "-h, --help  Print help (see more with '--help')"
    );
}

#[test]
fn render_writes_rgb_depth_and_mask_pngs() {
    let dir = temp_root("render");
    std::fs::create_dir_all(&dir).expect("temp dir");
    let (rgb, depth, mask) = (
        dir.join("rgb.png"),
        dir.join("depth.png"),
        dir.join("mask.png"),
    );
    let (code, stdout, stderr) = surgvla(&[
        "render",
        "--task",
        "T2-1",
        "--seed",
        "3",
        "--steps",
        "5",
        "--out",
        rgb.to_str().expect("utf-8"),
        "--depth",
        depth.to_str().expect("utf-8"),
        "--mask",
        mask.to_str().expect("utf-8"),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("triangles"));
    // The depth image's scale and the mask's legend are said, the images pixel-aligned.
    assert!(
        stdout.contains(" mm, nearest bright (yellow) to farthest dark (blue)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("mask ids 0 background, 1 table, 2 tray"),
        "{stdout}"
    );
    assert!(
        stdout.contains("6 gauze") && stdout.contains("17 distractor_needle"),
        "{stdout}"
    );
    for path in [&rgb, &depth, &mask] {
        let bytes = std::fs::read(path).expect("png written");
        assert_eq!(&bytes[1..4], b"PNG");
        // IHDR: 224 x 224.
        assert_eq!(&bytes[16..24], &[0, 0, 0, 224, 0, 0, 0, 224]);
    }
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .expect("list")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().ends_with(".partial"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left behind");
}

#[test]
fn contact_sheet_writes_one_grid_of_eight_scenes() {
    let sheet_dir = temp_root("sheet");
    std::fs::create_dir_all(&sheet_dir).expect("temp dir");
    let path = sheet_dir.join("sheet.png");
    let (code, stdout, stderr) = surgvla(&[
        "contact-sheet",
        "--out",
        path.to_str().expect("utf-8"),
        "--supersample",
        "1",
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("T3-2"));
    // 8 tiles of 224 with 4 px gaps by 3 rows, a margin on the left (row names, the depth
    // scale) and on top (column names), and the mask's legend under them.
    let (pixels, width) = crate::util::png_rgb(&path);
    let (left, top) = (
        surgvla::view::SHEET_LEFT_PX as usize,
        surgvla::view::SHEET_TOP_PX as usize,
    );
    assert_eq!(width, left + 8 * 228 - 4);
    let height = pixels.len() / 3 / width;
    let grid_bottom = top + 3 * 228 - 4;
    assert!(height > grid_bottom + 14, "{height}: no legend");
    let at = |x: usize, y: usize| {
        let i = (y * width + x) * 3;
        [pixels[i], pixels[i + 1], pixels[i + 2]]
    };
    let black_in = |x0: usize, x1: usize, y0: usize, y1: usize| {
        (y0..y1).any(|y| (x0..x1).any(|x| at(x, y) == [0, 0, 0]))
    };
    // Each column is named over its tile; the rows are named in the margin.
    for column in 0..8 {
        let x = left + column * 228;
        assert!(black_in(x, x + 64, 0, top), "column {column} has no name");
    }
    for row in 0..3 {
        let y = top + row * 228;
        assert!(black_in(0, left, y, y + 24), "row {row} has no name");
    }
    // The depth scale runs from the near colour (yellow) down to the far one (dark blue).
    let (near, far) = (at(10, top + 228 + 30), at(10, top + 2 * 228 - 50));
    assert!(near[0] > 200 && near[1] > 200, "{near:?}");
    assert!(far[2] > 100 && far[0] < 60, "{far:?}");
    // The legend: a swatch of the table's mask colour (id 1) and its name.
    let table = surgvla::render::image::mask_colour(1);
    assert!(
        (grid_bottom..height).any(|y| (0..width).any(|x| at(x, y) == table)),
        "no legend swatch of the table's colour"
    );
}

#[test]
fn render_into_a_missing_directory_exits_2_naming_the_path() {
    let (code, _, stderr) = surgvla(&["render", "--out", "/nonexistent-dir/frame.png"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("/nonexistent-dir/frame.png"), "{stderr}");
    assert!(!stderr.contains("panicked"));
}

#[test]
fn validate_json_reports_on_every_exit_code() {
    let (code, stdout, stderr) = surgvla(&["validate", "/nonexistent-dataset", "--json"]);
    assert_eq!(code, 2, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("a JSON report");
    assert_eq!(report["valid"], false);
    assert!(report["format"].is_null());
    let error = report["error"].as_str().expect("the reason");
    assert!(error.contains("/nonexistent-dataset"), "{error}");
}

#[test]
fn collect_writes_a_lerobot_dataset_and_refuses_to_overwrite_it() {
    let out = temp_root("collect");
    let path = out.to_str().expect("utf-8");
    let args = [
        "collect",
        "--tasks",
        "T1-1,needle_pick",
        "--episodes-per-task",
        "1",
        "--out",
        path,
    ];
    let (code, stdout, stderr) = surgvla(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("wrote 2 episodes"), "{stdout}");
    // The stages' times are said to be summed over threads; the process's CPU time beside.
    assert!(stdout.contains("time per stage, summed over "), "{stdout}");
    if cfg!(target_os = "linux") {
        assert!(stdout.contains("CPU time of the process: "), "{stdout}");
    }
    assert!(out.join("meta/info.json").exists());
    let (code, _, stderr) = surgvla(&args);
    assert_eq!(
        code, 2,
        "writing into a complete dataset is a user mistake: {stderr}"
    );
    assert!(stderr.contains(path), "{stderr}");
}

#[test]
fn collect_with_an_unknown_task_exits_2() {
    let (code, _, stderr) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1,T9-9",
        "--out",
        "/tmp/never-written",
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("unknown task 'T9-9'"), "{stderr}");
    assert!(!std::path::Path::new("/tmp/never-written").exists());
}

#[test]
fn collect_resume_starts_fresh_or_refuses_a_complete_dataset() {
    let out = temp_root("resume");
    let path = out.to_str().expect("utf-8");
    let args = [
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "2",
        "--resume",
        "--out",
        path,
    ];
    let (code, stdout, stderr) = surgvla(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("wrote 2 episodes"), "{stdout}");
    let (code, _, stderr) = surgvla(&args);
    assert_eq!(code, 2, "a complete dataset is not resumed: {stderr}");
}

#[test]
fn collect_into_a_file_or_under_one_exits_2_naming_the_path() {
    let folder = temp_root("out-is-a-file");
    std::fs::create_dir_all(&*folder).expect("folder");
    let file = folder.join("notes.txt");
    std::fs::write(&file, b"not a folder").expect("file");
    for out in [file.clone(), file.join("dataset")] {
        let path = out.to_str().expect("utf-8");
        let (code, _, stderr) = surgvla(&["collect", "--tasks", "T1-1", "--out", path]);
        assert_eq!(code, 2, "{path}: {stderr}");
        assert!(stderr.contains(path), "{stderr}");
        assert_eq!(
            stderr.lines().count(),
            1,
            "one line, each cause once: {stderr}"
        );
    }
    assert_eq!(std::fs::read(&file).expect("file"), b"not a folder");
}

#[test]
fn a_closed_output_pipe_is_a_quiet_exit() {
    for args in [vec!["tasks"], vec!["sim", "--task", "T1-3"]] {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
            .args(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("spawn");
        // Close the reading end before the first line is written.
        drop(child.stdout.take());
        let output = child.wait_with_output().expect("wait");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(0), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

#[test]
fn collect_without_depth_and_object_poses_writes_the_training_dataset() {
    let out = temp_root("without");
    let path = out.to_str().expect("utf-8");
    let (code, _, stderr) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "1",
        "--without",
        "depth,environment_state",
        "--out",
        path,
    ]);
    assert_eq!(code, 0, "{stderr}");
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("meta/info.json")).expect("info"))
            .expect("json");
    let features = info["features"].as_object().expect("features");
    assert!(features.contains_key("observation.images.endoscope"));
    assert!(features.contains_key("observation.state") && features.contains_key("action"));
    assert!(!features.contains_key("observation.images.depth"));
    assert!(!features.contains_key("observation.environment_state"));
    let (code, _, stderr) = surgvla(&["collect", "--without", "mask", "--out", path]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("depth, environment_state"), "{stderr}");
}

/// docs/commands.md shows every command's `--help` exactly as the CLI prints it, and the
/// README's table links every command: the documentation cannot drift from the code. After
/// changing the CLI: `SURGVLA_UPDATE_DOCS=1 cargo test --release --test all -- command_docs`.
#[test]
fn command_docs_show_the_clis_own_help() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("docs/commands.md");
    let text = std::fs::read_to_string(&path).expect("docs/commands.md");
    let (code, top, _) = surgvla(&["--help"]);
    assert_eq!(code, 0);
    let commands: Vec<String> = top
        .split("Commands:")
        .nth(1)
        .expect("a command list")
        .lines()
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .filter(|c| c != "help")
        .collect();
    assert!(commands.len() >= 14, "{commands:?}");
    let mut fresh = text.clone();
    for command in &commands {
        let marker = format!("<!-- help: {command} -->\n```text\n");
        let start = fresh
            .find(&marker)
            .unwrap_or_else(|| panic!("docs/commands.md has no help block for {command}"))
            + marker.len();
        let end = start + fresh[start..].find("```").expect("the block's end");
        let (code, help, _) = surgvla(&[command, "--help"]);
        assert_eq!(code, 0, "{command} --help");
        fresh.replace_range(start..end, &help);
    }
    if std::env::var_os("SURGVLA_UPDATE_DOCS").is_some() && fresh != text {
        std::fs::write(&path, &fresh).expect("write docs/commands.md");
        return;
    }
    assert!(
        fresh == text,
        "docs/commands.md differs from the CLI's help: SURGVLA_UPDATE_DOCS=1 cargo test --release --test all -- command_docs"
    );
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    for command in &commands {
        let link = format!("(docs/commands.md#surgvla-{command})");
        assert!(readme.contains(&link), "the README's table lacks {command}");
    }
}

/// Ctrl-C (SIGINT) in a long command: it says what the interruption leaves and how to go on,
/// and exits 130, as the README's table says; `--resume` then finishes the dataset.
#[test]
fn ctrl_c_exits_130_saying_how_to_resume() {
    let root = crate::util::temp_root("cli-ctrl-c");
    let out = root.join("data");
    let args = [
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "60",
        "--data-file-mb",
        "1",
        "--out",
        out.to_str().expect("utf-8"),
    ];
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    let marker = out.join(surgvla::export::INCOMPLETE_MARKER);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !marker.exists() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let sent = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(sent.success());
    let output = child.wait_with_output().expect("wait");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(
        stderr.contains("interrupted (Ctrl-C)") && stderr.contains("--resume"),
        "{stderr}"
    );
    let mut again = args.to_vec();
    again.push("--resume");
    let (code, _, err) = surgvla(&again);
    assert_eq!(code, 0, "{err}");
}

/// A log (stderr not a terminal) gets progress lines with the rate and the time left at the
/// interval asked for; `--quiet` gets none; a bad interval exits 2.
#[test]
fn progress_lines_go_to_a_log_at_the_interval_asked() {
    let root = crate::util::temp_root("cli-progress-lines");
    let out = |name: &str| root.join(name).to_str().expect("utf-8").to_string();
    let collect = |extra: &[&str], name: &str| {
        let target = out(name);
        let mut args = vec!["collect", "--tasks", "T1-1", "--episodes-per-task", "40"];
        args.extend(extra);
        args.extend(["--out", &target]);
        let (code, _, err) = surgvla(&args);
        assert_eq!(code, 0, "{err}");
        err
    };
    let err = collect(&["--progress-interval", "0.1"], "lines");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("collecting: "))
        .collect();
    assert!(!lines.is_empty(), "no progress line in {err}");
    assert!(
        lines
            .iter()
            .all(|l| l.contains("/40 episodes (") && l.contains("/s, ")),
        "{lines:?}"
    );
    let err = collect(&["--progress-interval", "0.1", "--quiet"], "quiet");
    assert!(!err.contains("collecting: "), "{err}");
    let (code, _, err) = surgvla(&["collect", "--progress-interval", "0", "--out", &out("bad")]);
    assert_eq!(code, 2, "{err}");
}

/// The README reads on a screen: no line over 400 characters (detail goes to docs/), and its
/// first code block, the quick start, is at most 15 lines (CI runs it as written).
#[test]
fn the_readme_is_readable() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    for (i, line) in readme.lines().enumerate() {
        assert!(
            line.chars().count() <= 400,
            "README.md line {} is {} characters",
            i + 1,
            line.chars().count()
        );
    }
    let start = readme.find("## Start here").expect("a Start here section");
    let block = readme[start..].split("```").nth(1).expect("a code block");
    let lines = block
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .count();
    assert!(
        (2..=15).contains(&lines),
        "the quick start has {lines} lines"
    );
    assert!(
        block.contains("cargo run --release -- collect") && block.contains("cargo test --release")
    );
}
