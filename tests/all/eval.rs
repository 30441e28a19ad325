//! Closed-loop evaluation: a policy server speaking openpi's protocol (here a tungstenite server
//! in a thread, answering as told per request: good chunks, wrong shapes, NaN, a closed
//! connection, a stall), the built-in references, seeds, determinism and the results files.

use crate::util::{surgvla, temp_root};
use rmpv::Value;
use std::net::TcpListener;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use surgvla::error::HasKind as _;
use surgvla::eval::{EvalOptions, PolicyChoice, evaluate, trial_seed};
use surgvla::task::TaskId;

/// How the fake server answers one request.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reply {
    /// A chunk of `n` actions: zero deltas, jaws open.
    Chunk(usize),
    WrongShape,
    Nan,
    /// Closes the connection without answering.
    Close,
    /// Answers only after this long.
    Stall(Duration),
    /// Sends a ping every 100 ms for this long, then answers (the time-out covers the whole
    /// reply, pings included).
    Pings(Duration),
    /// Sends an error text, as openpi's server does with its traceback.
    ErrorText,
    /// A chunk of 50 absurdly large (finite) actions: clipped by the workspace, never a panic.
    Huge,
}

fn array(dtype: &str, shape: &[u64], data: Vec<u8>) -> Value {
    Value::Map(vec![
        (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
        (Value::Binary(b"data".to_vec()), Value::Binary(data)),
        (Value::Binary(b"dtype".to_vec()), dtype.into()),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&d| Value::from(d)).collect()),
        ),
    ])
}

fn actions(rows: usize, values: impl Fn(usize) -> f32) -> Vec<u8> {
    let mut message = Vec::new();
    let data = (0..rows * 7)
        .flat_map(|i| values(i).to_le_bytes())
        .collect();
    let reply = Value::Map(vec![(
        "actions".into(),
        array("<f4", &[rows as u64, 7], data),
    )]);
    rmpv::encode::write_value(&mut message, &reply).expect("encode");
    message
}

/// What the server saw of one request: (key, dtype, shape) per array, and the prompt.
type Seen = (Vec<(String, String, Vec<u64>)>, String);

fn describe(bytes: &[u8]) -> Seen {
    let value = rmpv::decode::read_value(&mut &bytes[..]).expect("msgpack request");
    let Value::Map(fields) = value else {
        panic!("the request is a map")
    };
    let mut arrays = Vec::new();
    let mut prompt = String::new();
    for (key, value) in fields {
        let key = key.as_str().expect("string keys").to_string();
        match value {
            Value::String(s) => prompt = s.as_str().unwrap_or_default().to_string(),
            Value::Map(array) => {
                let get = |name: &[u8]| {
                    array
                        .iter()
                        .find(|(k, _)| k.as_slice() == Some(name))
                        .map(|(_, v)| v.clone())
                        .expect("array field under a binary key")
                };
                assert_eq!(get(b"__ndarray__"), Value::Boolean(true));
                let dtype = get(b"dtype").as_str().unwrap_or_default().to_string();
                let shape: Vec<u64> = get(b"shape")
                    .as_array()
                    .expect("shape")
                    .iter()
                    .map(|d| d.as_u64().expect("dimension"))
                    .collect();
                let width = if dtype == "|u1" { 1 } else { 4 };
                let data = get(b"data");
                let n: u64 = shape.iter().product();
                assert_eq!(data.as_slice().map(<[u8]>::len), Some((n * width) as usize));
                arrays.push((key, dtype, shape));
            }
            other => panic!("unexpected field {key}: {other}"),
        }
    }
    (arrays, prompt)
}

/// A policy server on a free local port answering the `script`'s replies in request order
/// (the last one repeats); returns its URL and what it saw.
fn serve(script: Vec<Reply>) -> (String, Arc<Mutex<Vec<Seen>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let url = format!("ws://{}", listener.local_addr().expect("address"));
    let seen = Arc::new(Mutex::new(Vec::new()));
    let counter = Arc::new(AtomicUsize::new(0));
    let log = seen.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { continue };
            let (script, log, counter) = (script.clone(), log.clone(), counter.clone());
            // A thread per connection: a stalled one must not keep the next from connecting.
            std::thread::spawn(move || {
                let Ok(mut socket) = tungstenite::accept(stream) else {
                    return;
                };
                let mut metadata = Vec::new();
                let meta = Value::Map(vec![("name".into(), "fake".into())]);
                rmpv::encode::write_value(&mut metadata, &meta).expect("encode");
                if socket
                    .send(tungstenite::Message::Binary(metadata.into()))
                    .is_err()
                {
                    return;
                }
                while let Ok(message) = socket.read() {
                    let tungstenite::Message::Binary(request) = message else {
                        continue;
                    };
                    log.lock().expect("log").push(describe(&request));
                    let n = counter.fetch_add(1, Ordering::SeqCst);
                    let reply = script[n.min(script.len() - 1)];
                    let bytes = match reply {
                        Reply::Chunk(rows) => actions(rows, |i| if i % 7 == 6 { 1.0 } else { 0.0 }),
                        Reply::WrongShape => {
                            let mut message = Vec::new();
                            let value = Value::Map(vec![(
                                "actions".into(),
                                array("<f4", &[6], vec![0; 24]),
                            )]);
                            rmpv::encode::write_value(&mut message, &value).expect("encode");
                            message
                        }
                        Reply::Nan => actions(1, |i| if i == 2 { f32::NAN } else { 0.0 }),
                        Reply::Huge => actions(50, |i| if i % 2 == 0 { 1e30 } else { -1e30 }),
                        Reply::Close => return,
                        Reply::Stall(pause) => {
                            std::thread::sleep(pause);
                            actions(1, |_| 0.0)
                        }
                        Reply::Pings(pause) => {
                            let started = std::time::Instant::now();
                            while started.elapsed() < pause {
                                let ping = tungstenite::Message::Ping(Vec::new().into());
                                if socket.send(ping).is_err() {
                                    return;
                                }
                                std::thread::sleep(Duration::from_millis(100));
                            }
                            actions(1, |_| 0.0)
                        }
                        Reply::ErrorText => {
                            let text = "Traceback: ValueError: bad observation".to_string();
                            let _ = socket.send(tungstenite::Message::Text(text.into()));
                            return;
                        }
                    };
                    if socket
                        .send(tungstenite::Message::Binary(bytes.into()))
                        .is_err()
                    {
                        return;
                    }
                }
            });
        }
    });
    (url, seen)
}

fn options(out: &std::path::Path, tasks: &[TaskId], trials: u32) -> EvalOptions {
    EvalOptions {
        tasks: tasks.to_vec(),
        trials,
        threads: 2,
        recordings_per_task: 1,
        out: out.to_path_buf(),
        ..EvalOptions::default()
    }
}

#[test]
fn a_remote_policy_gets_what_it_was_trained_on_and_chunks_are_replanned() {
    let out = temp_root("eval-remote");
    let (url, seen) = serve(vec![Reply::Chunk(8)]);
    let mut options = options(&out, &[TaskId::GauzePick], 2);
    options.replan_steps = Some(5);
    options.send.depth = true;
    options.recordings_per_task = 0;
    let report = evaluate(&PolicyChoice::Remote { url }, &options, &|_, _| {}).expect("eval");
    let row = &report.tasks[0];
    assert_eq!((row.trials, row.successes, row.policy_errors), (2, 0, 0));
    assert!(
        report.trials.iter().all(|t| t.steps == 100),
        "{:?}",
        report.trials
    );
    let seen = seen.lock().expect("log");
    // 100 steps per trial, 5 of each 8-action chunk executed: 20 requests per trial.
    assert_eq!(seen.len(), 40);
    let (arrays, prompt) = &seen[0];
    assert_eq!(prompt, "pick up the gauze");
    let expected = [
        ("observation/image", "|u1", vec![224, 224, 3]),
        ("observation/state", "<f4", vec![7]),
        ("observation/depth", "<f4", vec![224, 224]),
    ];
    let expected: Vec<(String, String, Vec<u64>)> = expected
        .into_iter()
        .map(|(k, d, s)| (k.to_string(), d.to_string(), s))
        .collect();
    assert_eq!(arrays, &expected);
    assert_eq!(report.policy_metadata["name"], "fake");
    // Labelled by the name the server gives itself; the options keep its URL.
    assert_eq!(report.policy, "fake");
    assert!(
        (report.options["policy"].as_str()).is_some_and(|u| u.starts_with("ws://")),
        "{}",
        report.options
    );
    assert_eq!(
        report.options["sent"]["observation/environment_state"],
        false
    );
}

#[test]
fn malformed_replies_fail_their_trial_with_the_reason_and_the_run_goes_on() {
    let out = temp_root("eval-malformed");
    let (url, _) = serve(vec![
        Reply::WrongShape,
        Reply::Nan,
        Reply::Close,
        Reply::Stall(Duration::from_millis(1500)),
        Reply::Pings(Duration::from_millis(3000)),
        Reply::ErrorText,
        Reply::Huge,
        Reply::Chunk(50),
    ]);
    let mut options = options(&out, &[TaskId::NeedlePick], 7);
    options.timeout = Duration::from_millis(500);
    let report = evaluate(&PolicyChoice::Remote { url }, &options, &|_, _| {}).expect("eval");
    let reasons: Vec<&str> = report.trials.iter().map(|t| t.reason.as_str()).collect();
    let expected = [
        "shape [6]",
        "[0, 2] is NaN",
        "closed the connection",
        "no reply from",
        "no reply from",
        "reported an error: Traceback: ValueError: bad observation",
        "step limit 100 reached",
    ];
    for (i, (reason, expected)) in reasons.iter().zip(expected).enumerate() {
        assert!(
            reason.contains(expected),
            "trial {i}: {reason} lacks {expected}"
        );
        assert_eq!(report.trials[i].policy_error, i < 6, "trial {i}");
    }
    assert_eq!(report.tasks[0].policy_errors, 6);
    // The first failure is recorded, with the seed that reproduces it in its name.
    let recording = report.trials[0].recording.as_deref().expect("a recording");
    assert!(
        recording.starts_with("failures/T1-2_trial000_seed"),
        "{recording}"
    );
    assert!(out.join(recording).is_file());
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).expect("results"))
            .expect("json");
    assert_eq!(written["tasks"][0]["policy_errors"], 6);
}

#[test]
fn an_unreachable_server_at_start_is_the_users_mistake() {
    let out = temp_root("eval-unreachable");
    // A port nobody listens on: bound, then released.
    let port = TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("address")
        .port();
    let url = format!("ws://127.0.0.1:{port}");
    let error = evaluate(
        &PolicyChoice::Remote { url: url.clone() },
        &options(&out, &[TaskId::GauzePick], 1),
        &|_, _| {},
    )
    .expect_err("nobody listens");
    assert_eq!(error.kind().exit_code(), 2);
    let (code, _, stderr) = surgvla(&[
        "eval",
        "--policy",
        &url,
        "--out",
        &out.display().to_string(),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(&format!("cannot connect to the policy server at {url}")),
        "{stderr}"
    );
    assert!(!out.join("results.json").exists());
}

#[test]
fn references_bound_the_table_the_expert_near_all_and_noop_none() {
    let out = temp_root("eval-references");
    let all = TaskId::ALL;
    let expert = evaluate(
        &PolicyChoice::Expert,
        &options(&out.join("expert"), &all, 6),
        &|_, _| {},
    )
    .expect("expert");
    for row in &expert.tasks {
        assert!(row.successes >= 5, "expert on {}: {:?}", row.task_id, row);
    }
    // The experts' tips stay on the tissue: an honest touch is within 1 mm of its surface.
    for trial in &expert.trials {
        assert!(
            (0.0..=1.0).contains(&trial.peak_penetration_mm),
            "{} trial {}: {} mm into an organ",
            trial.task_id,
            trial.trial,
            trial.peak_penetration_mm
        );
    }
    // Every predicate can fail: a policy that does nothing fails every task.
    let noop = evaluate(
        &PolicyChoice::Noop,
        &options(&out.join("noop"), &all, 3),
        &|_, _| {},
    )
    .expect("noop");
    for row in &noop.tasks {
        assert_eq!(row.successes, 0, "noop succeeded on {}", row.task_id);
    }
    assert!(
        noop.trials
            .iter()
            .all(|t| t.reason.starts_with("step limit"))
    );
    // Stages and failure classes: the expert's successes complete their chains; doing nothing
    // never reaches anything.
    for trial in expert.trials.iter().filter(|t| t.success) {
        assert_eq!(
            (trial.progress.progress, trial.progress.failure_class),
            (1.0, None)
        );
    }
    for trial in &noop.trials {
        let class = trial.progress.failure_class.map(|c| c.name());
        assert_eq!(
            (trial.progress.progress, class),
            (0.0, Some("never_reached")),
            "{trial:?}"
        );
    }
    // Random commands rarely get anywhere: progress near 0, failures of the early classes.
    let random = evaluate(
        &PolicyChoice::Random,
        &options(&out.join("random"), &all, 4),
        &|_, _| {},
    )
    .expect("random");
    let mean: f64 =
        random.tasks.iter().map(|t| t.mean_progress).sum::<f64>() / random.tasks.len() as f64;
    assert!(mean < 0.15, "random's mean progress {mean}");
    for trial in random.trials.iter().filter(|t| !t.success) {
        let class = trial.progress.failure_class.map(|c| c.name());
        assert!(
            matches!(
                class,
                Some(
                    "never_reached"
                        | "reached_no_grasp"
                        | "grasped_wrong_object"
                        | "unsafe"
                        | "dropped"
                        | "timed_out"
                )
            ),
            "{trial:?}"
        );
    }
    // results.json follows its schema, which refuses what it does not describe.
    for run in ["expert", "noop"] {
        let text = std::fs::read_to_string(out.join(run).join("results.json")).expect("results");
        let mut json: serde_json::Value = serde_json::from_str(&text).expect("json");
        let schema = surgvla::eval::results::RESULTS_JSON_SCHEMA;
        assert_eq!(
            surgvla::export::schema::check_text(&json, schema),
            vec![],
            "{run}"
        );
        json["trials"][0]["progress"] = 1.5.into();
        json["tasks"][0]["failure_classes"]["stabbed"] = 1.into();
        assert_eq!(
            surgvla::export::schema::check_text(&json, schema).len(),
            2,
            "{run}"
        );
    }
    // Three failures per task recorded as MCAP that validates.
    let recorded: Vec<&str> = noop
        .trials
        .iter()
        .filter_map(|t| t.recording.as_deref())
        .collect();
    assert_eq!(recorded.len(), 8);
    let (code, stdout, stderr) = surgvla(&[
        "validate",
        &out.join("noop").join(recorded[0]).display().to_string(),
    ]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let markdown = std::fs::read_to_string(out.join("noop/results.md")).expect("results.md");
    assert!(
        markdown
            .contains("| policy | T1-1 | T1-2 | T1-3 | T2-1 | T2-2 | T2-3 | T3-1 | T3-2 | mean |"),
        "{markdown}"
    );
    assert!(markdown.contains("| noop | 0.0 | 0.0 |"), "{markdown}");
    // The precision table: every task a row, noop's figures absent or zero.
    assert!(
        markdown.contains("| T1-1 | - | - | - | - | 0.00 | 0 | - |"),
        "{markdown}"
    );
    let expert_md = std::fs::read_to_string(out.join("expert/results.md")).expect("results.md");
    let row = (expert_md.lines())
        .find(|l| l.starts_with("| T3-1 |") && l.matches('|').count() == 9)
        .expect("T3-1's precision row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let covered: f64 = cells[4].parse().expect("covered %");
    assert!((40.0..=70.0).contains(&covered), "{row}");
    let csv = std::fs::read_to_string(out.join("expert/results.csv")).expect("results.csv");
    assert_eq!(csv.lines().count(), 9);
    // results.png, and the two runs charted side by side by `surgvla report`.
    let png = std::fs::read(out.join("expert/results.png")).expect("results.png");
    assert_eq!(&png[1..4], b"PNG");
    let chart = out.join("chart.png");
    let (expert_dir, noop_dir) = (out.join("expert"), out.join("noop"));
    // With the survival cascade: every stage of every task, the expert's bars full, noop's
    // empty.
    let cascade = out.join("cascade.png");
    let (code, stdout, stderr) = surgvla(&[
        "report",
        &expert_dir.display().to_string(),
        &noop_dir.display().to_string(),
        "--out",
        &chart.display().to_string(),
        "--cascade",
        &cascade.display().to_string(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("charted 2 runs over 8 tasks"), "{stdout}");
    assert!(
        stdout.contains("drew the survival cascade (29 stages)"),
        "{stdout}"
    );
    let runs = [&expert_dir, &noop_dir].map(|d| surgvla::eval::chart::read_results(d).unwrap());
    let names = ["expert".to_string(), "noop".to_string()];
    let title = surgvla::eval::chart::CASCADE_TITLE;
    let stages = surgvla::eval::chart::cascade_of(title, &runs, &names).expect("stages");
    let (canvas, layout) = surgvla::chart::plots::rate_chart(&stages);
    let labels: Vec<&str> = (stages.categories.iter().take(3))
        .map(|c| c.label.as_str())
        .collect();
    assert_eq!(labels, ["reach", "grasp", "lift"]);
    let bar = |category: usize, series: usize| {
        let x = layout.bar_x(category, series) + 2;
        let colour = surgvla::chart::SERIES[series];
        (0..surgvla::chart::plots::BarLayout::zero_y())
            .rev()
            .take_while(|&y| canvas.at(x, y) == Some(colour))
            .count()
    };
    // The expert's first T1-1 trials: all six reached (a whole bar), noop none.
    assert_eq!(bar(0, 0), surgvla::chart::plots::PLOT_HEIGHT_PX);
    assert_eq!(
        bar(0, 1),
        surgvla::chart::plots::MIN_BAR_PX,
        "0 % shows as a stub"
    );
    let (drawn, _) = crate::util::png_rgb(&cascade);
    assert!(
        drawn == canvas.pixels,
        "the command drew what the library draws"
    );
    let report_png = std::fs::read(&chart).expect("chart");
    let (code, _, _) = surgvla(&[
        "report",
        &expert_dir.display().to_string(),
        &noop_dir.display().to_string(),
        "--out",
        &chart.display().to_string(),
    ]);
    assert_eq!(code, 0);
    assert_eq!(
        std::fs::read(&chart).expect("chart"),
        report_png,
        "same runs, same bytes"
    );
    let (code, _, stderr) = surgvla(&[
        "report",
        &out.join("nothing").display().to_string(),
        "--out",
        &chart.display().to_string(),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("holds no results.json"), "{stderr}");
    // A chart is PNG: a name that says otherwise is refused before anything is read.
    let jpg = out.join("chart.jpg");
    let (code, _, stderr) = surgvla(&[
        "report",
        &expert_dir.display().to_string(),
        "--out",
        &jpg.display().to_string(),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("ending in .png") && !jpg.exists(),
        "{stderr}"
    );
}

/// The chart's bars follow the numbers: read at the places the layout puts each run's bar.
#[test]
fn the_report_chart_draws_each_rate_where_the_layout_says() {
    use surgvla::chart::plots::{BarLayout, PLOT_HEIGHT_PX, rate_chart};
    use surgvla::eval::chart::{RunRates, TaskRate, chart_of};
    let run = |policy: &str, rates: &[(&str, u8, f64)]| RunRates {
        policy: policy.into(),
        tasks: rates
            .iter()
            .map(|&(id, level, rate)| TaskRate {
                task_id: id.into(),
                level,
                success_rate: rate,
                ci95_low: rate,
                ci95_high: rate,
                variant: "none".into(),
                success_drop: None,
                trials: 4,
                successes: (4.0 * rate) as u32,
                stages: Default::default(),
            })
            .collect(),
    };
    // Tasks come out by level then id, whatever order the runs list them in.
    let runs = [
        run("a", &[("T3-1", 3, 0.5), ("T1-1", 1, 1.0)]),
        run("b", &[("T1-1", 1, 0.25)]),
    ];
    let chart = chart_of("t", &runs, &["a".into(), "b".into()]);
    let labels: Vec<&str> = chart.categories.iter().map(|c| c.label.as_str()).collect();
    assert_eq!(labels, ["T1-1", "T3-1"]);
    let (canvas, layout) = rate_chart(&chart);
    let height = |category: usize, series: usize| {
        let x = layout.bar_x(category, series) + 2;
        let colour = surgvla::chart::SERIES[series];
        (0..BarLayout::zero_y())
            .rev()
            .take_while(|&y| canvas.at(x, y) == Some(colour))
            .count()
    };
    assert_eq!(height(0, 0), PLOT_HEIGHT_PX);
    assert_eq!(height(1, 0), PLOT_HEIGHT_PX / 2);
    assert_eq!(height(0, 1), PLOT_HEIGHT_PX / 4);
    assert_eq!(height(1, 1), 0, "b has no T3-1");
}

#[test]
fn results_are_a_function_of_the_seed_not_of_the_threads() {
    let out = temp_root("eval-determinism");
    let run = |threads: usize, seed: u64, name: &str| {
        let mut options = options(
            &out.join(name),
            &[TaskId::GauzePick, TaskId::Electrocoagulation],
            4,
        );
        (options.threads, options.seed) = (threads, seed);
        evaluate(&PolicyChoice::Random, &options, &|_, _| {}).expect("random");
        std::fs::read(out.join(name).join("results.json")).expect("results")
    };
    let one = run(1, 5, "one");
    assert_eq!(one, run(2, 5, "two"));
    assert_ne!(one, run(2, 6, "other"));
    assert_eq!(
        crate::util::tree(&out.join("one/failures")),
        crate::util::tree(&out.join("two/failures"))
    );
}

#[test]
fn evaluation_seeds_are_disjoint_from_collection_seeds() {
    use std::collections::BTreeSet;
    let mut collected = BTreeSet::new();
    for task in TaskId::ALL {
        for k in 0..100 {
            for attempt in 0..20 {
                collected.insert(surgvla::collect::record::attempt_seed(0, task, k, attempt));
            }
        }
    }
    for task in TaskId::ALL {
        for trial in 0..200 {
            let seed = trial_seed(0, task, trial);
            assert!(
                !collected.contains(&seed),
                "{task} trial {trial}: seed {seed}"
            );
        }
    }
    // The needle spawns over the reference's evaluation range (+-0.03 m), wider than collection's.
    let config = EvalOptions::default().task_config(TaskId::NeedlePick);
    assert_eq!(config.spawn_scale, 3.0);
    let xs: Vec<f64> = (0..50)
        .map(|i| {
            let instance = TaskId::NeedlePick
                .instance(trial_seed(0, TaskId::NeedlePick, i), &config)
                .expect("spawn");
            instance.scene.objects[0].world_from_object.translation.x
        })
        .collect();
    let spread =
        xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 0.03, "the needle's x spans only {spread} m");
}

#[test]
fn replay_plays_the_nearest_training_episode_of_the_task() {
    let out = temp_root("eval-replay");
    let data = out.join("data");
    let (code, _, stderr) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "3",
        "--out",
        &data.display().to_string(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let choice = PolicyChoice::Replay {
        dataset: data.clone(),
    };
    let report = evaluate(
        &choice,
        &options(&out.join("eval"), &[TaskId::GauzePick], 4),
        &|_, _| {},
    )
    .expect("replay");
    assert!(
        report
            .trials
            .iter()
            .all(|t| t.replayed_episode.is_some_and(|e| e < 3))
    );
    assert!(report.tasks[0].successes >= 1, "{:?}", report.trials);
    // A task the dataset lacks is refused before any trial runs.
    let error = evaluate(
        &choice,
        &options(&out.join("none"), &[TaskId::Hemostasis], 1),
        &|_, _| {},
    )
    .expect_err("no T3-2 episodes");
    assert_eq!(error.kind().exit_code(), 2);
    assert!(error.to_string().contains("has no episode of"), "{error}");
}

#[test]
fn the_command_prints_the_eight_task_table_and_refuses_bad_policies() {
    let out = temp_root("eval-cli");
    let dir = out.display().to_string();
    let (code, stdout, stderr) =
        surgvla(&["eval", "--policy", "expert", "--trials", "2", "--out", &dir]);
    assert_eq!(code, 0, "{stderr}");
    // Aligned columns, as collect prints them (results.md has the Markdown table).
    let head = "task name trials successes rate 95 % CI mean steps";
    assert!(
        (stdout.lines()).any(|l| l.split_whitespace().collect::<Vec<_>>().join(" ") == head),
        "{stdout}"
    );
    let rows: Vec<&str> = stdout.lines().filter(|l| l.starts_with('T')).collect();
    assert_eq!(rows.len(), 8, "{stdout}");
    assert!(
        (rows.iter()).all(|r| r.split_whitespace().skip(2).take(3).eq(["2", "2", "100.0"])),
        "{stdout}"
    );
    // Each column is aligned: the rates end at the same place on every row.
    let ends: Vec<usize> = rows.iter().map(|r| r.find(" %").expect("rate")).collect();
    assert!(ends.iter().all(|e| *e == ends[0]), "{stdout}");
    assert!(rows.iter().all(|r| r.len() <= 80), "{stdout}");
    assert!(
        stdout.contains("mean success rate 100.0 % over 8 tasks (16 of 16 trials)"),
        "{stdout}"
    );
    // The survival cascade under the table.
    let cascade = "- T3-1 (2 trials): reached 2 -> grasped 2 -> lifted 2 -> transported 2 -> released_on_target 2 -> settled 2; progress 1.00; failures: none";
    assert!(stdout.contains(cascade), "{stdout}");
    for (args, said) in [
        (
            vec!["--policy", "replay"],
            "--policy replay needs --dataset DIR",
        ),
        (
            vec!["--policy", "greedy"],
            "neither ws://HOST:PORT nor one of",
        ),
        (
            vec!["--policy", "wss://example.org"],
            "wss:// is not supported",
        ),
        (vec!["--policy", "noop", "--tasks", "T9-9"], "unknown task"),
        (
            vec!["--policy", "noop", "--timeout-secs", "0"],
            "--timeout-secs must be a positive",
        ),
        (
            vec!["--policy", "noop", "--send", "mask"],
            "invalid value 'mask'",
        ),
    ] {
        let mut full = vec!["eval"];
        full.extend(args);
        full.extend(["--out", &dir]);
        let (code, _, stderr) = surgvla(&full);
        assert_eq!(code, 2, "{full:?}: {stderr}");
        assert!(stderr.contains(said), "{full:?}: {stderr}");
    }
    let (code, _, stderr) = surgvla(&[
        "eval",
        "--policy",
        "noop",
        "--trials",
        "1",
        "--out",
        "Cargo.toml",
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("Cargo.toml is a file"), "{stderr}");
}

/// The results folder belongs to one run: locked while it lasts, never mixed with another
/// run's results (replaced only with `--replace`) or with other files.
#[test]
fn the_results_folder_is_not_shared() {
    let root = temp_root("eval-out");
    let out = root.join("results");
    let dir = out.display().to_string();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "eval", "--policy", "noop", "--tasks", "T1-1", "--trials", "1", "--out", &dir,
        ];
        args.extend(extra);
        surgvla(&args)
    };
    assert_eq!(run(&[]).0, 0);
    let (code, _, stderr) = run(&[]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("--replace"), "{stderr}");
    let (code, _, stderr) = run(&["--replace", "--name", "still arm"]);
    assert_eq!(code, 0, "{stderr}");
    let results: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).expect("results"))
            .expect("json");
    assert_eq!(results["policy"], "still arm");
    assert_eq!(results["options"]["policy"], "noop");
    // Held by another process: refused while the lock lasts.
    let held = std::fs::File::open(&out).expect("open");
    held.try_lock().expect("lock");
    let (code, _, stderr) = run(&["--replace"]);
    assert_eq!(code, 2, "{stderr}");
    drop(held);
    std::fs::write(out.join("notes.txt"), b"mine").expect("write");
    let (code, _, stderr) = run(&["--replace"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("notes.txt"), "{stderr}");
    assert_eq!(std::fs::read(out.join("notes.txt")).expect("kept"), b"mine");
}

/// A task whose every trial failed on the policy exits 1 (a CI gate sees it), with the table and
/// the results written.
#[test]
fn a_policy_that_never_answers_fails_the_run() {
    let root = temp_root("eval-errors");
    let (url, _) = serve(vec![Reply::WrongShape]);
    let dir = root.join("results").display().to_string();
    let (code, stdout, stderr) = surgvla(&[
        "eval",
        "--policy",
        &url,
        "--tasks",
        "T1-1",
        "--trials",
        "2",
        "--out",
        &dir,
        "--timeout-secs",
        "2",
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("every trial of T1-1 failed on policy errors"),
        "{stderr}"
    );
    assert!(stdout.lines().any(|l| l.starts_with("T1-1 ")), "{stdout}");
    assert!(root.join("results/results.json").is_file());
}

/// `args` (an eval) run to the end in `out`.
fn eval_into(out: &std::path::Path, args: &[&str]) -> (i32, String, String) {
    let dir = out.display().to_string();
    let mut all = vec!["eval"];
    all.extend(args);
    all.extend(["--out", &dir]);
    surgvla(&all)
}

/// The journal of `out` cut after its first `keep` trials, with half of the next line (what an
/// interruption leaves), and the results files gone.
fn interrupt_after(out: &std::path::Path, keep: usize) {
    let journal = out.join(".eval-journal.jsonl");
    let text = std::fs::read_to_string(&journal).expect("journal");
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines.len() > keep + 1, "{} lines", lines.len());
    let mut cut: String = lines[..=keep].iter().map(|l| format!("{l}\n")).collect();
    cut.push_str(&lines[keep + 1][..lines[keep + 1].len() / 2]);
    std::fs::write(&journal, cut).expect("cut");
    for name in ["results.json", "results.csv", "results.md", "results.png"] {
        std::fs::remove_file(out.join(name)).expect("remove");
    }
}

#[test]
fn an_interrupted_evaluation_resumes_to_the_uninterrupted_bytes() {
    let root = temp_root("eval-resume");
    let args = [
        "--policy",
        "random",
        "--tasks",
        "T1-1,T1-2",
        "--trials",
        "3",
        "--record-failures",
        "1",
    ];
    let (whole, cut) = (root.join("whole"), root.join("cut"));
    for out in [&whole, &cut] {
        let (code, _, err) = eval_into(out, &args);
        assert_eq!(code, 0, "{err}");
    }
    interrupt_after(&cut, 3);
    // Without --resume, the folder is said to hold an interrupted run, not another run's results.
    let (code, _, err) = eval_into(&cut, &args);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("holds an interrupted evaluation (3 trials scored); give --resume"),
        "{err}"
    );
    // Another evaluation's journal is refused.
    let mut other = args.to_vec();
    other[5] = "4";
    other.push("--resume");
    let (code, _, err) = eval_into(&cut, &other);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("another evaluation's"), "{err}");
    let mut resumed = args.to_vec();
    resumed.push("--resume");
    let (code, out, err) = eval_into(&cut, &resumed);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("resumed: 3 trials scored"), "{out}");
    assert_eq!(crate::util::tree(&cut), crate::util::tree(&whole));
    // Resuming a finished run scores nothing again and writes the same results.
    let (code, out, err) = eval_into(&cut, &resumed);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("resumed: 6 trials scored"), "{out}");
    assert_eq!(crate::util::tree(&cut), crate::util::tree(&whole));
}

#[test]
fn a_served_policys_evaluation_resumes_trial_by_trial() {
    let root = temp_root("eval-remote-resume");
    let (url, seen) = serve(vec![Reply::Chunk(8)]);
    let choice = PolicyChoice::Remote { url };
    let (whole, cut) = (root.join("whole"), root.join("cut"));
    for out in [&whole, &cut] {
        let options = options(out, &[TaskId::GauzePick, TaskId::NeedlePick], 2);
        evaluate(&choice, &options, &|_, _| {}).expect("eval");
    }
    interrupt_after(&cut, 1);
    let asked = seen.lock().expect("log").len();
    let mut options = options(&cut, &[TaskId::GauzePick, TaskId::NeedlePick], 2);
    options.resume = true;
    let report = evaluate(&choice, &options, &|_, _| {}).expect("resumed");
    assert_eq!(report.resumed_trials, 1);
    // Three trials of 100 steps, 13 chunks of 8 actions each, were run again; the first was not.
    assert_eq!(seen.lock().expect("log").len() - asked, 39);
    assert_eq!(crate::util::tree(&cut), crate::util::tree(&whole));
}

#[test]
fn ctrl_c_in_an_evaluation_exits_130_and_resume_finishes_it() {
    let root = temp_root("eval-ctrl-c");
    let args = [
        "--policy",
        "random",
        "--tasks",
        "L1",
        "--trials",
        "2",
        "--threads",
        "1",
    ];
    let (whole, cut) = (root.join("whole"), root.join("cut"));
    let (code, _, err) = eval_into(&whole, &args);
    assert_eq!(code, 0, "{err}");
    let dir = cut.display().to_string();
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .arg("eval")
        .args(args)
        .args(["--out", &dir])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    // Interrupted once the first task's trials are journaled (three tasks remain).
    let journal = cut.join(".eval-journal.jsonl");
    let scored = || std::fs::read_to_string(&journal).map_or(0, |t| t.lines().count());
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while scored() < 3 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    let signal = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(signal.success());
    let output = child.wait_with_output().expect("wait");
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{err}");
    assert!(err.contains("--resume"), "{err}");
    let mut resumed = args.to_vec();
    resumed.push("--resume");
    let (code, out, err) = eval_into(&cut, &resumed);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("resumed:"), "{out}");
    assert_eq!(crate::util::tree(&cut), crate::util::tree(&whole));
}
