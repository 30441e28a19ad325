//! The `surgvla` binary: user mistakes exit 2 with a clear message, runs print the trajectory.

use std::process::Command;

fn surgvla(args: &[&str]) -> (i32, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .args(args)
        .output()
        .expect("run surgvla");
    (
        output.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn sim_shows_a_grasp_lift_and_release() {
    let (code, stdout, stderr) = surgvla(&[
        "sim",
        "--task",
        "gauze_pick",
        "--seed",
        "1",
        "--steps",
        "40",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let grasp = stdout.find("grasp").expect("a grasp event");
    let release = stdout.find("release").expect("a release event");
    assert!(grasp < release, "{stdout}");
    assert!(stdout.contains("trajectory digest"));
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
