//! The `surgvla` command line: parses arguments, dispatches to the library, prints the error
//! chain once and maps its kind to the exit code (0 done; 1 the work failed or the data is
//! invalid; 2 the command could not start because of what the user gave).

/// Writes a line to stdout; a failed write (a closed pipe) returns an error with `?`, which
/// `main` treats as a quiet exit when the pipe was closed.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($arg)*)?
    }};
}

mod commands;
mod error;
mod formats;
mod job;
mod memory;
mod progress;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "surgvla",
    version,
    about = "Datasets for surgical robot learning: simulate, collect, export, validate"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the task's scripted expert in a scene and print the trajectory and the verdict.
    Sim(commands::sim::SimArgs),
    /// Render a task scene from the endoscope: RGB, and optionally depth and mask
    /// visualisations, as PNG.
    Render(commands::render::RenderArgs),
    /// Render the start frame of all eight tasks into one PNG grid (RGB, depth and mask rows).
    ContactSheet(commands::contact_sheet::ContactSheetArgs),
    /// Record verified expert episodes of the tasks and write a dataset in any output format
    /// (defaults: all eight tasks, 100 episodes each, LeRobot v3.0 into ./data).
    Collect(commands::collect::CollectArgs),
    /// Convert a dataset into another format: `convert INPUT --to rlds --out DIR`.
    Convert(commands::convert::ConvertArgs),
    /// Turn robot recordings (ROS 1 bags, ROS 2 MCAP files) into a dataset, synchronised by a
    /// stated rule with a report per input: `ingest A.bag B.mcap --camera left=/camera/left/image_raw --out DIR`.
    Ingest(commands::ingest::IngestArgs),
    /// Simulate one expert episode and record it as MCAP for Foxglove: images, depth, point
    /// cloud, the instrument's frames, the scene's meshes, state and action.
    Record(commands::record::RecordArgs),
    /// Measure the experts' success rates as `collect` would run them (same attempts and replay
    /// check) without rendering or writing: the quick check of a new or edited plan.
    Experts(commands::experts::ExpertsArgs),
    /// Merge datasets of one format (the outputs of `collect --shard I/N` or `convert --shard
    /// I/N`, or any compatible ones) into one: episodes re-indexed, files rolled as one run rolls
    /// them; all N shards merged are the single run's bytes.
    Merge(commands::merge::MergeArgs),
    /// Score a policy in closed loop on the tasks: a VLA behind openpi's policy-server protocol
    /// (`--policy ws://HOST:PORT`) or a built-in reference (expert, replay, random, noop);
    /// writes results.json, results.csv, results.md and results.png (the chart) with Wilson 95 %
    /// intervals.
    Eval(commands::eval::EvalArgs),
    /// Chart several evaluations' success rates side by side (`report RESULTS_DIR... --out
    /// chart.png`): each task's rate with its 95 % interval, one colour per run, tasks grouped by
    /// level.
    Report(commands::report::ReportArgs),
    /// Check a dataset (LeRobot v3.0/v2.1, RLDS, DP3 zarr, MCAP; ours or not) frame by frame
    /// and name every defect: exit 0 valid, 1 invalid, 2 nothing recognisable at the path.
    Validate(commands::validate::ValidateArgs),
    /// Describe a dataset: format, episodes, frames, features, tasks, size, provenance.
    Info(commands::info::InfoArgs),
    /// Print a format's features schema (what schemas/lerobot_features.json and
    /// schemas/rlds_features.json record).
    Schema(commands::schema::SchemaArgs),
    /// List the tasks: id, level, name, step limit, canonical instruction and paraphrases.
    Tasks,
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(error) => {
            let code = if error.use_stderr() { 2 } else { 0 };
            let _ = error.print();
            return ExitCode::from(code);
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
    // Before any thread exists (parsing starts none).
    memory::limit_arenas(match &cli.command {
        Command::Collect(args) => memory::collect_arenas(args.job.threads.unwrap_or(0)),
        _ => 1,
    });
    let result = match cli.command {
        Command::Sim(args) => commands::sim::run_sim(&args),
        Command::Render(args) => commands::render::run_render(&args),
        Command::ContactSheet(args) => commands::contact_sheet::run_contact_sheet(&args),
        Command::Collect(args) => commands::collect::run_collect(&args),
        Command::Convert(args) => commands::convert::run_convert(&args),
        Command::Ingest(args) => commands::ingest::run_ingest(&args),
        Command::Record(args) => commands::record::run_record(&args),
        Command::Experts(args) => commands::experts::run_experts(&args),
        Command::Merge(args) => commands::merge::run_merge(&args),
        Command::Eval(args) => commands::eval::run_eval(&args),
        Command::Report(args) => commands::report::run_report(&args),
        Command::Validate(args) => commands::validate::run_validate(&args),
        Command::Info(args) => commands::info::run_info(&args),
        Command::Schema(args) => commands::schema::run_schema(&args),
        Command::Tasks => commands::tasks::run_tasks(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) if error.quiet => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", error.message());
            ExitCode::from(error.kind.exit_code())
        }
    }
}
