//! Perturbation suites: visual and language variants leave the physics alone (the privileged
//! expert scores the same trials the same way under each), every visual dimension changes the
//! images and nothing else, scene dimensions move what they name, and the command line runs a
//! suite, records it, refuses bad variants and draws the heatmap.

use crate::util::{surgvla, temp_root};
use surgvla::env::{Env, EnvOptions};
use surgvla::eval::perturb::{Dimensions, Kind, Suite, Variant};
use surgvla::eval::{EvalOptions, PolicyChoice, evaluate, trial_seed};
use surgvla::task::TaskId;

#[test]
fn the_expert_holds_under_every_visual_and_language_perturbation() {
    let out = temp_root("perturb-expert");
    let mut variants = Suite::builtin("visual-v1").unwrap().variants;
    variants.extend(
        Suite::builtin("language-v1")
            .unwrap()
            .variants
            .into_iter()
            .skip(1),
    );
    assert_eq!(variants.len(), 1 + 13 + 3);
    let options = EvalOptions {
        tasks: TaskId::ALL.to_vec(),
        trials: 3,
        threads: 2,
        recordings_per_task: 0,
        out: out.to_path_buf(),
        suite: Some(Suite::one_off(variants.clone())),
        // Rendered, effects and all: the images change, the physics must not.
        render_builtin: true,
        ..EvalOptions::default()
    };
    let report = evaluate(&PolicyChoice::Expert, &options, &|_, _| {}).expect("expert");
    assert_eq!(report.tasks.len(), 8 * variants.len());
    let baseline: Vec<_> = report
        .trials
        .iter()
        .filter(|t| t.variant == "none")
        .collect();
    for variant in variants.iter().skip(1).map(Variant::name) {
        let trials: Vec<_> = report
            .trials
            .iter()
            .filter(|t| t.variant == variant)
            .collect();
        assert_eq!(trials.len(), baseline.len(), "{variant}");
        let successes = trials.iter().filter(|t| t.success).count();
        assert!(
            successes * 100 >= 99 * trials.len(),
            "{variant}: {successes} of {}",
            trials.len()
        );
        for (t, b) in trials.iter().zip(&baseline) {
            // The same scene, moved the same way, to the same end.
            assert_eq!(
                (&t.task_id, t.seed, t.success, t.steps, t.progress.progress),
                (&b.task_id, b.seed, b.success, b.steps, b.progress.progress),
                "{variant}"
            );
            assert!(!t.perturbation.is_empty(), "{variant} records what it drew");
            if t.success {
                assert_eq!(t.progress.progress, 1.0);
            }
        }
        for row in report.tasks.iter().filter(|r| r.variant == variant) {
            assert_eq!(row.success_drop, Some(0.0), "{variant} {}", row.task_id);
        }
    }
    // Language variants changed the instruction, and say so.
    let told = |variant: &str| {
        (report.trials.iter())
            .find(|t| t.variant == variant && t.task_id == "T2-1")
            .map(|t| t.instruction.clone())
            .unwrap()
    };
    assert_eq!(told("detailed=1"), "pick up the gauze, not the needle");
    assert_eq!(told("absent_object=1"), "pick up the block");
    assert!(TaskId::GauzePick.paraphrases().iter().any(|p| {
        report
            .trials
            .iter()
            .any(|t| t.variant == "paraphrase=1" && t.instruction == *p)
    }));
    // The run records its suite, and results.json follows the schema.
    let text = std::fs::read_to_string(out.join("results.json")).expect("results");
    let json: serde_json::Value = serde_json::from_str(&text).expect("json");
    assert_eq!(json["suite"]["name"], "perturb");
    assert_eq!(
        json["suite"]["variants"].as_array().unwrap().len(),
        variants.len()
    );
    let schema = surgvla::eval::results::RESULTS_JSON_SCHEMA;
    assert_eq!(surgvla::export::schema::check_text(&json, schema), vec![]);
}

#[test]
fn each_visual_dimension_changes_the_images_and_nothing_else() {
    let dimensions = Dimensions::v1();
    let task = TaskId::Hemostasis;
    let seed = trial_seed(0, task, 1);
    let instance = task.instance(seed, &Default::default()).unwrap();
    let (_, plain) = Env::from_instance(instance.clone(), &EnvOptions::default());
    let plain_images = plain.images.clone().unwrap();
    for (kind, spec) in &dimensions.specs {
        if *kind != Kind::Visual {
            continue;
        }
        let variant = Variant::parse(&format!("{}=2", spec.name), dimensions).unwrap();
        let drawn = variant.draw(dimensions, seed);
        assert_eq!(
            drawn.task_config(Default::default()),
            Default::default(),
            "{}",
            spec.name
        );
        let options = EnvOptions {
            camera: drawn.camera(&EnvOptions::default().camera),
            appearance: Some(drawn.appearance),
            effects: drawn.effects,
            ..EnvOptions::default()
        };
        let (_, seen) = Env::from_instance(instance.clone(), &options);
        let images = seen.images.clone().unwrap();
        // The instrument is a small part of the view: judged on its own pixels.
        let instrument = spec.name == "instrument_appearance";
        let judged: Vec<usize> = (0..plain_images.mask.len())
            .filter(|&p| !instrument || (3..=5).contains(&plain_images.mask[p]))
            .collect();
        let changed = (judged.iter())
            .filter(|&&p| {
                (0..3).any(|c| images.rgb[p * 3 + c].abs_diff(plain_images.rgb[p * 3 + c]) > 2)
            })
            .count();
        assert!(
            changed * 20 > judged.len(),
            "{}: only {changed} of {} pixels changed",
            spec.name,
            judged.len()
        );
        // Depth and mask move only with the camera; the state never.
        if spec.name != "camera_pose" {
            assert_eq!(images.depth_m, plain_images.depth_m, "{}", spec.name);
            assert_eq!(images.mask, plain_images.mask, "{}", spec.name);
        } else {
            assert_ne!(images.mask, plain_images.mask);
        }
        assert_eq!(seen.state, plain.state, "{}", spec.name);
        assert_eq!(seen.environment_state, plain.environment_state);
    }
}

#[test]
fn scene_perturbations_move_what_they_name() {
    let dimensions = Dimensions::v1();
    let seed = trial_seed(0, TaskId::GauzePickDistractors, 0);
    let task = TaskId::GauzePickDistractors;
    let instance = |given: &str| {
        let drawn = Variant::parse(given, dimensions)
            .unwrap()
            .draw(dimensions, seed);
        let mut instance = task
            .instance(seed, &drawn.task_config(Default::default()))
            .unwrap();
        let start = surgvla::sim::SimConfig::default()
            .world_from_start_tip
            .translation
            .vector;
        drawn.apply_to_instance(&mut instance, start);
        (instance, drawn)
    };
    let (plain, _) = instance("none");
    let distractors =
        |i: &surgvla::task::TaskInstance| i.scene.objects.iter().filter(|o| o.distractor).count();
    assert_eq!(distractors(&plain), 1);
    // Level 2 is three distractors (level 1 two).
    assert_eq!(distractors(&instance("distractors=1").0), 2);
    assert_eq!(distractors(&instance("distractors=2").0), 3);
    // Similar distractors look like the target (the scene stays as it was).
    let (similar, drawn) = instance("distractor_similarity=3");
    assert_eq!(similar, plain);
    let look = |appearance| {
        let options = EnvOptions {
            appearance: Some(appearance),
            ..EnvOptions::default()
        };
        let (_, seen) = Env::from_instance(plain.clone(), &options);
        seen.images.unwrap()
    };
    let (before, after) = (look(Default::default()), look(drawn.appearance));
    // The distractor's pixels (a needle, mask id 17) go from grey metal to the gauze's white.
    let mean_of = |images: &surgvla::env::Images| {
        let pixels: Vec<usize> = (0..images.mask.len())
            .filter(|&p| images.mask[p] == 17)
            .collect();
        assert!(pixels.len() > 20, "the distractor is in view");
        pixels
            .iter()
            .map(|&p| f64::from(images.rgb[p * 3]))
            .sum::<f64>()
            / pixels.len() as f64
    };
    assert!(mean_of(&after) > mean_of(&before) + 20.0);
    assert_eq!(before.mask, after.mask);
    // The tip starts the drawn distance away, in the horizontal plane.
    let (moved, drawn) = instance("instrument_start=3");
    let (_, first) = Env::from_instance(moved, &EnvOptions::headless());
    let (_, usual) = Env::from_instance(plain.clone(), &EnvOptions::headless());
    let shift_mm: Vec<f64> = (0..3)
        .map(|i| f64::from(first.state[i] - usual.state[i]) * 1000.0)
        .collect();
    let mm = drawn.values["tip_start_offset_mm"].as_f64().unwrap();
    assert!((15.0..=18.0).contains(&mm));
    let horizontal = shift_mm[0].hypot(shift_mm[1]);
    assert!(
        (horizontal - mm).abs() < 0.5 && shift_mm[2].abs() < 0.5,
        "{shift_mm:?} vs {mm}"
    );
    // A wider spawn range spreads the gauze wider over the trials.
    let spread = |given: &str| {
        let drawn = Variant::parse(given, dimensions)
            .unwrap()
            .draw(dimensions, 0);
        let config = drawn.task_config(Default::default());
        (0..40)
            .map(|k| {
                let i = TaskId::GauzePick.instance(trial_seed(0, TaskId::GauzePick, k), &config);
                let p = i.unwrap().scene.objects[0]
                    .world_from_object
                    .translation
                    .vector;
                (p.x - 0.55).abs().max(p.y.abs())
            })
            .fold(0.0, f64::max)
    };
    assert!(spread("spawn_range=3") > 1.5 * spread("none"));
}

#[test]
fn the_command_runs_a_suite_records_it_and_draws_its_heatmap() {
    let out = temp_root("perturb-cli");
    let (code, help, _) = surgvla(&["eval", "--help"]);
    assert_eq!(code, 0);
    for suite in surgvla::eval::perturb::SUITE_FILES.map(|(name, _)| name) {
        assert!(help.contains(suite), "--help lists {suite}");
    }
    let run = |extra: &[&str]| {
        let dir = out.join("run");
        let mut args = vec![
            "eval",
            "--policy",
            "noop",
            "--tasks",
            "T1-1,T1-3",
            "--trials",
            "2",
        ];
        args.extend_from_slice(&["--record-failures", "1", "--replace", "--out"]);
        let dir = dir.display().to_string();
        args.push(&dir);
        args.extend_from_slice(extra);
        surgvla(&args)
    };
    for (extra, says) in [
        (
            &["--perturb", "fog=1"][..],
            "unknown perturbation dimension `fog`",
        ),
        (
            &["--perturb", "smoke=9"][..],
            "`smoke` has levels 1 to 3, not 9",
        ),
        (
            &["--suite", "visual-v1", "--perturb", "smoke=1"][..],
            "cannot be used with",
        ),
        (&["--suite", "visual-v9"][..], "invalid value 'visual-v9'"),
    ] {
        let (code, _, stderr) = run(extra);
        assert_eq!(code, 2, "{extra:?}: {stderr}");
        assert!(stderr.contains(says), "{extra:?}: {stderr}");
    }
    let (code, stdout, stderr) = run(&["--perturb", "none", "--perturb", "smoke=1,blur=2"]);
    assert_eq!(code, 0, "{stderr}");
    // The grid in aligned columns on the terminal (results.md has it in Markdown).
    let row = (stdout.lines())
        .find(|l| l.starts_with("smoke=1,blur=2 "))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(row.contains(" 0 [0-66] (±0)"), "{stdout}");
    let markdown = std::fs::read_to_string(out.join("run/results.md")).unwrap();
    assert!(
        markdown.contains("| smoke=1,blur=2 | 0 [0-66] (±0) |"),
        "{markdown}"
    );
    let dir = out.join("run");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("results.json")).unwrap()).unwrap();
    assert_eq!(
        json["suite"]["variants"],
        serde_json::json!(["none", "smoke=1,blur=2"])
    );
    // Variant after variant, task after task: the perturbed trials follow the four plain ones.
    let trial = &json["trials"][4];
    assert_eq!(trial["variant"], "smoke=1,blur=2");
    assert!(trial["perturbation"]["smoke_fraction"].as_f64().unwrap() >= 0.15);
    assert_eq!(trial["perturbation"]["blur_radius_px"], 2);
    // Each variant's failures are recorded apart (the trials share their seeds).
    let recordings = std::fs::read_dir(dir.join("failures")).unwrap().count();
    assert_eq!(recordings, 4);
    // The report of a suite's run is its heatmap: every cell 0 %, coloured so.
    let chart = out.join("heat.png");
    let (code, stdout, stderr) = surgvla(&[
        "report",
        &dir.display().to_string(),
        "--out",
        &chart.display().to_string(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("as a heatmap of 2 variants over 2 tasks"),
        "{stdout}"
    );
    let (pixels, width) = crate::util::png_rgb(&chart);
    use surgvla::chart::heatmap::{colour_of, column_x, row_y};
    let left = 16 + 8 * "smoke=1,blur=2".len();
    for (r, c) in [(0, 0), (1, 1), (1, 2)] {
        let (x, y) = (column_x(left, c) + 3, row_y(r) + 3);
        let i = (y * width + x) * 3;
        assert_eq!(pixels[i..i + 3], colour_of(0.0), "cell ({r}, {c})");
    }
}
