//! The command tree (clap derive) and [`run`]: parses the arguments, dispatches to one file per
//! command, prints the error chain once and maps its kind to the exit code (0 done; 1 the work
//! failed or the data is invalid; 2 the command could not start because of what the user gave).

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "surgvla",
    version,
    about = "Datasets for surgical robot learning: simulate, collect, export, validate"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Print no progress (no bars on a terminal, no progress lines elsewhere).
    #[arg(long, global = true, help_heading = "Running")]
    quiet: bool,
    /// When stderr is not a terminal (a log file, a batch job), print a progress line (done,
    /// rate, time left) every this many seconds.
    #[arg(long, global = true, value_name = "SECS", default_value_t = 10.0, value_parser = progress_interval, help_heading = "Running")]
    progress_interval: f64,
}

/// `--progress-interval`: a positive number of seconds, at most a day.
fn progress_interval(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(secs) if secs.is_finite() && secs > 0.0 && secs <= 86_400.0 => Ok(secs),
        _ => Err(format!(
            "{text:?} is not a number of seconds between 0 and 86400"
        )),
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the task's scripted expert in a scene and print the trajectory and the verdict.
    Sim(crate::commands::sim::SimArgs),
    /// Render a task scene from the endoscope: RGB, and optionally depth and mask
    /// visualisations, as PNG.
    Render(crate::commands::render::RenderArgs),
    /// Render the start frame of all eight tasks into one PNG grid (RGB, depth and mask rows).
    ContactSheet(crate::commands::contact_sheet::ContactSheetArgs),
    /// Record verified expert episodes of the tasks and write a dataset in any output format
    /// (defaults: all eight tasks, 100 episodes each, LeRobot v3.0 into ./data).
    Collect(crate::commands::collect::CollectArgs),
    /// Convert a dataset into another format: `convert INPUT --to rlds --out DIR`.
    Convert(crate::commands::convert::ConvertArgs),
    /// Turn robot recordings (ROS 1 bags, ROS 2 MCAP files) into a dataset, synchronised by a
    /// stated rule with a report per input: `ingest A.bag B.mcap --camera left=/camera/left/image_raw --out DIR`.
    Ingest(crate::commands::ingest::IngestArgs),
    /// Simulate one expert episode and record it as MCAP for Foxglove: images, depth, point
    /// cloud, the instrument's frames, the scene's meshes, state and action.
    Record(crate::commands::record::RecordArgs),
    /// Measure the experts' success rates as `collect` would run them (same attempts and replay
    /// check) without rendering or writing: the quick check of a new or edited plan.
    Experts(crate::commands::experts::ExpertsArgs),
    /// Merge datasets of one format (the outputs of `collect --shard I/N` or `convert --shard
    /// I/N`, or any compatible ones) into one: episodes re-indexed, files rolled as one run rolls
    /// them; all N shards merged are the single run's bytes.
    Merge(crate::commands::merge::MergeArgs),
    /// Edit a dataset in its own format, video copied without decoding: keep or drop episodes
    /// (indices, task, length, success, validate's findings), split them (seeded, stratified
    /// by task), remove or rename features, change instructions: `edit IN --drop 1,3,6-8 --out DIR`.
    Edit(crate::commands::edit::EditArgs),
    /// Score a policy in closed loop on the tasks: a VLA behind openpi's policy-server protocol
    /// (`--policy ws://HOST:PORT`) or a built-in reference (expert, replay, random, noop);
    /// writes results.json, results.csv, results.md and results.png (the chart) with Wilson 95 %
    /// intervals.
    Eval(crate::commands::eval::EvalArgs),
    /// Chart several evaluations' success rates side by side (`report RESULTS_DIR... --out
    /// chart.png`): each task's rate with its 95 % interval, one colour per run, tasks grouped by
    /// level.
    Report(crate::commands::report::ReportArgs),
    /// Check a dataset (LeRobot v3.0/v2.1, RLDS, DP3 zarr, MCAP; ours or not) frame by frame
    /// and name every defect: exit 0 valid, 1 invalid, 2 nothing recognisable at the path.
    Validate(crate::commands::validate::ValidateArgs),
    /// Describe a dataset: format, episodes, frames, features, tasks, size, provenance.
    Info(crate::commands::info::InfoArgs),
    /// Print a format's features schema (what schemas/lerobot_features.json and
    /// schemas/rlds_features.json record).
    Schema(crate::commands::schema::SchemaArgs),
    /// List the tasks: id, level, name, step limit, canonical instruction and paraphrases.
    Tasks,
}

/// A PNG file to write (`--out` of the charts and pictures): a name ending in `.png`, since
/// the bytes written are PNG (a `.jpg` name would hold PNG bytes).
pub(crate) fn png_path(text: &str) -> Result<std::path::PathBuf, String> {
    let path = std::path::PathBuf::from(text);
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("png") => Ok(path),
        _ => Err(format!(
            "{text:?}: surgvla draws PNG; give a file name ending in .png"
        )),
    }
}

/// `--threads N` of every command, checked in this one place: 0 means one per core, and at most
/// [`surgvla::collect::slot::MAX_THREADS_PER_CORE`] per core (a bad value exits 2).
pub(crate) fn threads_arg(text: &str) -> Result<usize, String> {
    use surgvla::collect::slot::{MAX_THREADS_PER_CORE, cores};
    let threads: usize = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of threads"))?;
    let max = MAX_THREADS_PER_CORE * cores();
    if threads > max {
        return Err(format!(
            "at most {max} threads on this machine ({MAX_THREADS_PER_CORE} per core; 0: one per core)"
        ));
    }
    Ok(threads)
}

/// Runs the command line `args` (the program name first) and returns the exit code: what the
/// binary's `main` and the Python module's console script (`surgvla` installed by pip) both call.
pub(crate) fn run(args: impl IntoIterator<Item = std::ffi::OsString>) -> u8 {
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(error) => {
            let code = if error.use_stderr() { 2 } else { 0 };
            let _ = error.print();
            return code;
        }
    };
    // A damaged MP4 the demuxer panics on is reported as an error naming the file; its panic
    // message stays off the terminal. Other panics are printed as before.
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !surgvla::media::in_quiet_parse() {
            previous(info);
        }
    }));
    crate::progress::show(crate::progress::Shown {
        quiet: cli.quiet,
        interval: std::time::Duration::from_secs_f64(cli.progress_interval),
    });
    // Before any thread exists (parsing starts none).
    crate::memory::limit_arenas(match &cli.command {
        Command::Collect(args) => crate::memory::collect_arenas(args.job.threads.unwrap_or(0)),
        _ => 1,
    });
    let result = match cli.command {
        Command::Sim(args) => crate::commands::sim::run_sim(&args),
        Command::Render(args) => crate::commands::render::run_render(&args),
        Command::ContactSheet(args) => crate::commands::contact_sheet::run_contact_sheet(&args),
        Command::Collect(args) => crate::commands::collect::run_collect(&args),
        Command::Convert(args) => crate::commands::convert::run_convert(&args),
        Command::Ingest(args) => crate::commands::ingest::run_ingest(&args),
        Command::Record(args) => crate::commands::record::run_record(&args),
        Command::Experts(args) => crate::commands::experts::run_experts(&args),
        Command::Merge(args) => crate::commands::merge::run_merge(&args),
        Command::Edit(args) => crate::commands::edit::run_edit(&args),
        Command::Eval(args) => crate::commands::eval::run_eval(&args),
        Command::Report(args) => crate::commands::report::run_report(&args),
        Command::Validate(args) => crate::commands::validate::run_validate(&args),
        Command::Info(args) => crate::commands::info::run_info(&args),
        Command::Schema(args) => crate::commands::schema::run_schema(&args),
        Command::Tasks => crate::commands::tasks::run_tasks(),
    };
    match result {
        Ok(()) => 0,
        Err(error) if error.quiet => 0,
        Err(error) => {
            eprintln!("error: {}", error.message());
            error.kind.exit_code()
        }
    }
}
