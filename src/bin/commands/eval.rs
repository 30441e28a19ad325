//! `surgvla eval`: closed-loop evaluation of a policy on the tasks (see `surgvla::eval`). Turns
//! the arguments into `EvalOptions`, shows a progress bar per task and prints the results table.

use crate::error::CliError;
use crate::job::{Instructions, TaskList, parse_tasks};
use crate::progress::TrialBars;
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use std::time::Duration;
use surgvla::eval::perturb::{Dimensions, Suite, Variant};
use surgvla::eval::{EvalOptions, PolicyChoice, SendExtras, evaluate};

/// `--policy`: a server address or a built-in policy.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum PolicyArg {
    Remote(String),
    Builtin(Builtin),
}

/// The built-in reference policies.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Builtin {
    /// The task's scripted expert (the upper bound).
    Expert,
    /// The actions of the nearest training episode of `--dataset` (same task), open loop.
    Replay,
    /// Seeded uniform random commands (a lower bound).
    Random,
    /// Zero deltas with the jaws open (a lower bound).
    Noop,
}

fn parse_policy(text: &str) -> Result<PolicyArg, String> {
    if text.starts_with("ws://") || text.starts_with("wss://") {
        return Ok(PolicyArg::Remote(text.to_string()));
    }
    Builtin::from_str(text, true)
        .map(PolicyArg::Builtin)
        .map_err(|_| {
            format!("'{text}' is neither ws://HOST:PORT nor one of expert, replay, random, noop")
        })
}

/// What a remote policy may be sent beyond the image, the state and the prompt.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SendFeature {
    /// `observation/depth`, float32 (224, 224), metres.
    Depth,
    /// `observation/environment_state`, float32 (28,): ground-truth object poses (privileged).
    #[value(name = "environment_state")]
    EnvironmentState,
}

/// `--suite`: the perturbation suites (each a versioned file in `suites/`).
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SuiteArg {
    /// Every visual dimension at level 2 (light, camera, tissue, drape, smoke, blood,
    /// highlights, noise, blur, instrument), one at a time, after the unperturbed run.
    #[value(name = "visual-v1")]
    VisualV1,
    /// Every visual dimension at levels 1, 2 and 3: severity curves.
    #[value(name = "visual-levels-v1")]
    VisualLevelsV1,
    /// Spawn range, distractor count and the instrument's start, at level 2.
    #[value(name = "scene-v1")]
    SceneV1,
    /// Paraphrases, detailed prompts, and an instruction naming an absent object.
    #[value(name = "language-v1")]
    LanguageV1,
    /// The paper's first prompt study: canonical, then paraphrased instructions.
    #[value(name = "prompts-paraphrase-v1")]
    PromptsParaphraseV1,
    /// The paper's second prompt study: canonical, then detailed instructions.
    #[value(name = "prompts-detailed-v1")]
    PromptsDetailedV1,
    /// Every dimension once: visual and scene at level 2 and the language probes.
    #[value(name = "all-v1")]
    AllV1,
}

impl SuiteArg {
    /// The suite's file name (without `.json`).
    pub(crate) fn file(self) -> &'static str {
        match self {
            SuiteArg::VisualV1 => "visual-v1",
            SuiteArg::VisualLevelsV1 => "visual-levels-v1",
            SuiteArg::SceneV1 => "scene-v1",
            SuiteArg::LanguageV1 => "language-v1",
            SuiteArg::PromptsParaphraseV1 => "prompts-paraphrase-v1",
            SuiteArg::PromptsDetailedV1 => "prompts-detailed-v1",
            SuiteArg::AllV1 => "all-v1",
        }
    }
}

#[derive(Args, Debug)]
pub(crate) struct EvalArgs {
    /// The policy: `ws://HOST:PORT` (a server of openpi's protocol), or expert, replay, random,
    /// noop.
    #[arg(long, value_parser = parse_policy)]
    policy: PolicyArg,
    /// The dataset whose episodes `--policy replay` plays (any format `convert` reads).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Tasks: "all" or a comma-separated list of names, ids (T1-1) and levels (L1: its tasks).
    #[arg(long, default_value = "all", value_parser = parse_tasks)]
    tasks: TaskList,
    /// Trials per task (the benchmark uses 50).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    trials: u32,
    /// Evaluation seed: every trial's scene derives from it, from a stream disjoint from
    /// collection's.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The prompt per trial: the canonical instruction, a seeded paraphrase, or a seeded mix
    /// (the prompt-robustness study).
    #[arg(long, value_enum, default_value = "canonical")]
    instructions: Instructions,
    /// Distractors in T2-1 and T2-2.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=3))]
    distractors: u64,
    /// Scale every task's spawn ranges by F (default: the reference's evaluation ranges, i.e.
    /// 3 for the needle of T1-2 and 1 elsewhere).
    #[arg(long)]
    spawn_scale: Option<f64>,
    /// Also send the remote policy these observations (comma-separated).
    #[arg(long, value_enum, value_delimiter = ',')]
    send: Vec<SendFeature>,
    /// Execute the first K actions of each returned chunk before asking again (default: all).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    replan_steps: Option<u64>,
    /// Seconds to wait for the server to connect and for each reply.
    #[arg(long, default_value_t = 30.0)]
    timeout_secs: f64,
    /// Worker threads for the built-in policies (default and 0: one per core; at most 8 per
    /// core).
    #[arg(long, value_parser = crate::app::threads_arg)]
    threads: Option<usize>,
    /// Failed trials per task to record as MCAP under OUT/failures/ [default: 3 for a served
    /// policy, 0 for the built-in ones, whose failures any run reproduces from their seeds].
    #[arg(long, value_name = "N")]
    record_failures: Option<usize>,
    /// The results folder (results.json, results.csv, results.md, failures/): new or empty.
    #[arg(long, default_value = "eval")]
    out: PathBuf,
    /// Replace an earlier run's results in --out (never other files).
    #[arg(long, conflicts_with = "resume")]
    replace: bool,
    /// The policy's name in the results, tables and charts [default: a served policy's own,
    /// from its metadata's `name`, `policy_name` or `policy`, else its URL; a built-in
    /// policy's name].
    #[arg(long, value_name = "NAME", value_parser = policy_name)]
    name: Option<String>,
    /// Continue an interrupted run of this evaluation in --out from the trials it scored
    /// (kept in --out/.eval-journal.jsonl); the results equal an uninterrupted run's.
    #[arg(long)]
    resume: bool,
    /// Run every task under each variant of a perturbation suite (the unperturbed trials
    /// first; every variant on the same seeds). docs/eval.md lists the dimensions and levels.
    #[arg(long, value_enum, conflicts_with = "perturb")]
    suite: Option<SuiteArg>,
    /// Run every task under this variant, DIMENSION=LEVEL[,DIMENSION=LEVEL...] (e.g.
    /// `smoke=2` or `light_intensity=1,blur=1`); repeat for several variants, `none` for the
    /// unperturbed trials.
    #[arg(long, value_name = "DIM=LEVEL,...")]
    perturb: Vec<String>,
    /// Render every observation for the built-in policies too (they read the simulator, so
    /// this only costs the time a served policy's evaluation spends rendering).
    #[arg(long)]
    render_images: bool,
}

impl EvalArgs {
    fn choice(&self) -> Result<PolicyChoice, CliError> {
        Ok(match (&self.policy, &self.dataset) {
            (PolicyArg::Remote(url), _) => PolicyChoice::Remote { url: url.clone() },
            (PolicyArg::Builtin(Builtin::Replay), Some(dataset)) => PolicyChoice::Replay {
                dataset: dataset.clone(),
            },
            (PolicyArg::Builtin(Builtin::Replay), None) => {
                return Err(CliError::usage(
                    "--policy replay needs --dataset DIR (the training dataset)".to_string(),
                ));
            }
            (PolicyArg::Builtin(Builtin::Expert), _) => PolicyChoice::Expert,
            (PolicyArg::Builtin(Builtin::Random), _) => PolicyChoice::Random,
            (PolicyArg::Builtin(Builtin::Noop), _) => PolicyChoice::Noop,
        })
    }

    fn options(&self) -> Result<EvalOptions, CliError> {
        if !(self.timeout_secs.is_finite() && self.timeout_secs > 0.0) {
            return Err(CliError::usage(format!(
                "--timeout-secs must be a positive number of seconds, not {}",
                self.timeout_secs
            )));
        }
        if let Some(scale) = self.spawn_scale
            && !(scale.is_finite() && scale >= 0.0)
        {
            return Err(CliError::usage(format!(
                "--spawn-scale must be a number >= 0, not {scale}"
            )));
        }
        let threads = match self.threads {
            None | Some(0) => surgvla::collect::slot::cores(),
            Some(n) => n,
        };
        let suite = match (self.suite, self.perturb.as_slice()) {
            (Some(suite), _) => Some(Suite::builtin(suite.file())?),
            (None, []) => None,
            (None, given) => {
                let dimensions = Dimensions::v1();
                let variants = (given.iter())
                    .map(|v| Variant::parse(v, dimensions))
                    .collect::<Result<_, _>>()?;
                Some(Suite::one_off(variants))
            }
        };
        Ok(EvalOptions {
            tasks: self.tasks.0.clone(),
            trials: self.trials,
            seed: self.seed,
            instruction: self.instructions.choice(),
            distractors: self.distractors as usize,
            spawn_scale: self.spawn_scale,
            send: SendExtras {
                depth: self.send.contains(&SendFeature::Depth),
                environment_state: self.send.contains(&SendFeature::EnvironmentState),
            },
            replan_steps: self.replan_steps.map(|k| k as usize),
            timeout: Duration::from_secs_f64(self.timeout_secs),
            threads: threads.max(1),
            recordings_per_task: self.record_failures.unwrap_or(match self.policy {
                PolicyArg::Remote(_) => 3,
                _ => 0,
            }),
            out: self.out.clone(),
            replace: self.replace,
            resume: self.resume,
            name: self.name.clone(),
            suite,
            render_builtin: self.render_images,
            ..EvalOptions::default()
        })
    }
}

pub(crate) fn run_eval(args: &EvalArgs) -> Result<(), CliError> {
    let choice = args.choice()?;
    let options = args.options()?;
    let variants = options.variants().len() as u32;
    let bars = TrialBars::new(&options.tasks, options.trials * variants);
    crate::interrupt::writing(&options.out, true);
    let report = evaluate(&choice, &options, &|task, done| bars.set(task, done));
    bars.clear();
    let report = report?;
    if report.resumed_trials > 0 {
        say!(
            "resumed: {} scored by the interrupted run",
            crate::say::n(report.resumed_trials as u64, "trial")
        );
    }
    say!("policy: {}", report.policy);
    match report.variants_terminal() {
        // A suite's rows are many: the grid here, every row in results.md.
        Some(grid) => say!("{}", grid.trim_end()),
        None => {
            say!("{}", report.terminal_table().trim_end());
            say!("{}", report.stages_markdown().trim_end());
        }
    }
    // The totals are the unperturbed rows' when the run has them (all rows otherwise).
    let perturbed_with_baseline = variants > 1 && report.tasks.iter().any(|t| t.variant == "none");
    say!(
        "mean success rate {:.1} % over {} tasks ({} of {} trials{}); results in {}",
        100.0 * report.overall.mean_success_rate,
        options.tasks.len(),
        report.overall.successes,
        report.overall.trials,
        if perturbed_with_baseline {
            ", unperturbed"
        } else {
            ""
        },
        options.out.display()
    );
    let errors: u32 = report.tasks.iter().map(|t| t.policy_errors).sum();
    if errors > 0 {
        let first = report.trials.iter().find(|t| t.policy_error);
        say!(
            "{errors} trials failed because the policy did not answer properly; first: {}",
            first.map_or("", |t| t.reason.as_str())
        );
    }
    // A task whose every trial failed on the policy measured nothing: the run failed (exit 1),
    // so that a CI gate sees it; the table and the results files are written all the same.
    let unmeasured: Vec<&str> = report
        .tasks
        .iter()
        .filter(|t| t.trials > 0 && t.policy_errors == t.trials)
        .map(|t| t.task_id.as_str())
        .collect();
    if !unmeasured.is_empty() {
        return Err(CliError::invalid(format!(
            "every trial of {} failed on policy errors: the policy was not evaluated there",
            unmeasured.join(", ")
        )));
    }
    Ok(())
}

/// `--name`: a label of 1 to 64 characters, no control characters.
fn policy_name(text: &str) -> Result<String, String> {
    surgvla::eval::policy_label(text)
        .ok_or_else(|| "a name of 1 to 64 characters, without control characters".into())
}
