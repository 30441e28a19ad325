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

mod episodes;
mod error;
mod eval;
mod formats;
mod inspect;
mod memory;
mod progress;

use clap::{Parser, Subcommand};
use error::CliError;
use formats::SchemaFormat;
use std::path::PathBuf;
use std::process::ExitCode;
use surgvla::assets::{Appearance, SceneAssets};
use surgvla::collect::rollout;
use surgvla::policy::ExpertLibrary;
use surgvla::render::image::{depth_visualisation, mask_visualisation, write_png_file};
use surgvla::render::{Camera, Lighting, RenderOptions, Renderer};
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;
use surgvla::view::{contact_sheet, render_simulator};

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
    Sim(SimArgs),
    /// Render a task scene from the endoscope: RGB, and optionally depth and mask
    /// visualisations, as PNG.
    Render(RenderArgs),
    /// Render the start frame of all eight tasks into one PNG grid (RGB, depth and mask rows).
    ContactSheet(ContactSheetArgs),
    /// Record verified expert episodes of the tasks and write a dataset in any output format
    /// (defaults: all eight tasks, 100 episodes each, LeRobot v3.0 into ./data).
    Collect(episodes::CollectArgs),
    /// Convert a dataset into another format: `convert INPUT --to rlds --out DIR`.
    Convert(formats::ConvertArgs),
    /// Simulate one expert episode and record it as MCAP for Foxglove: images, depth, point
    /// cloud, the instrument's frames, the scene's meshes, state and action.
    Record(RecordArgs),
    /// Measure the experts' success rates as `collect` would run them (same attempts and replay
    /// check) without rendering or writing: the quick check of a new or edited plan.
    Experts(episodes::ExpertsArgs),
    /// Merge datasets of one format (the outputs of `collect --shard I/N` or `convert --shard
    /// I/N`, or any compatible ones) into one: episodes re-indexed, files rolled as one run rolls
    /// them; all N shards merged are the single run's bytes.
    Merge(formats::MergeArgs),
    /// Score a policy in closed loop on the tasks: a VLA behind openpi's policy-server protocol
    /// (`--policy ws://HOST:PORT`) or a built-in reference (expert, replay, random, noop);
    /// writes results.json, results.csv, results.md and results.png (the chart) with Wilson 95 %
    /// intervals.
    Eval(eval::EvalArgs),
    /// Chart several evaluations' success rates side by side (`report RESULTS_DIR... --out
    /// chart.png`): each task's rate with its 95 % interval, one colour per run, tasks grouped by
    /// level.
    Report(eval::ReportArgs),
    /// Check a dataset (LeRobot v3.0/v2.1, RLDS, DP3 zarr, MCAP; ours or not) frame by frame
    /// and name every defect: exit 0 valid, 1 invalid, 2 nothing recognisable at the path.
    Validate(inspect::ValidateArgs),
    /// Describe a dataset: format, episodes, frames, features, tasks, size, provenance.
    Info(inspect::InfoArgs),
    /// Print a format's features schema (what schemas/lerobot_features.json and
    /// schemas/rlds_features.json record).
    Schema {
        /// Include the segmentation mask feature.
        #[arg(long)]
        with_mask: bool,
        /// The format: lerobot (info.json's features), rlds (features.json) or mcap (the JSON
        /// channels' schemas).
        #[arg(long, value_enum, default_value = "lerobot")]
        format: SchemaFormat,
    },
    /// List the tasks: id, level, name, step limit, canonical instruction and paraphrases.
    Tasks,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum CameraChoice {
    /// The endoscope (224 x 224, 60 deg).
    Endoscope,
    /// A wider overview of the workspace.
    Overview,
}

#[derive(clap::Args, Debug)]
struct RenderArgs {
    /// Task name (gauze_pick, ...) or id (T1-1, ...).
    #[arg(long, default_value = "gauze_pick")]
    task: TaskId,
    /// Episode seed: decides the spawn positions and shapes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Run this many steps of the task's expert before rendering.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=100_000))]
    steps: u32,
    /// Output PNG for the RGB image.
    #[arg(long)]
    out: PathBuf,
    /// Also write the depth, colour-mapped (near bright, far dark, background black).
    #[arg(long)]
    depth: Option<PathBuf>,
    /// Also write the segmentation mask, colour-coded by object id.
    #[arg(long)]
    mask: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "endoscope")]
    camera: CameraChoice,
    #[command(flatten)]
    look: LookArgs,
}

#[derive(clap::Args, Debug)]
struct LookArgs {
    /// Supersampling of RGB per pixel edge (1 = off, 2 = 4 samples a pixel).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    supersample: u32,
    /// Randomise light, tissue colour and texture contrast from the seed.
    #[arg(long)]
    randomize_appearance: bool,
    /// Light every surface per pixel (by default dense tissue is lit per vertex; slower).
    #[arg(long)]
    per_pixel_lighting: bool,
}

#[derive(clap::Args, Debug)]
struct ContactSheetArgs {
    /// Output PNG.
    #[arg(long, default_value = "contact_sheet.png")]
    out: PathBuf,
    /// Seed of every scene.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[command(flatten)]
    look: LookArgs,
}

impl LookArgs {
    fn options(&self, seed: u64) -> (RenderOptions, Appearance) {
        let appearance = if self.randomize_appearance {
            Appearance::randomized(seed)
        } else {
            Appearance::default()
        };
        let options = RenderOptions {
            lighting: Lighting {
                allow_per_vertex: !self.per_pixel_lighting,
                ..appearance.lighting(Lighting::default())
            },
            supersample: self.supersample,
            ..RenderOptions::default()
        };
        (options, appearance)
    }
}

fn run_render(args: &RenderArgs) -> Result<(), CliError> {
    let instance = args
        .task
        .instance(args.seed, &surgvla::task::TaskConfig::default())?;
    let scene = instance.scene.clone();
    let mut sim = Simulator::new(SimConfig::default(), scene.clone());
    if args.steps > 0 {
        let library = ExpertLibrary::builtin()?;
        let mut policy =
            library
                .plan(args.task)?
                .expert(&instance, &sim.observation(), args.seed)?;
        rollout(&mut sim, &mut policy, args.steps);
    }
    let camera = match args.camera {
        CameraChoice::Endoscope => Camera::endoscope(),
        CameraChoice::Overview => Camera::overview(),
    };
    let (options, appearance) = args.look.options(args.seed);
    let assets = SceneAssets::new(&scene, args.seed, appearance);
    let mut renderer = Renderer::new(options);
    let frame = render_simulator(&assets, &mut renderer, &camera, &sim);
    let (w, h) = (frame.width_px, frame.height_px);
    write_png_file(&args.out, w, h, 3, &frame.rgb)?;
    if let Some(path) = &args.depth {
        write_png_file(path, w, h, 3, &depth_visualisation(&frame))?;
    }
    if let Some(path) = &args.mask {
        write_png_file(path, w, h, 3, &mask_visualisation(&frame))?;
    }
    say!(
        "{} ({}), seed {}, step {}: {} triangles, wrote {}",
        args.task.code(),
        args.task.name(),
        args.seed,
        sim.observation().step_index,
        assets.triangle_count(),
        args.out.display()
    );
    Ok(())
}

fn run_contact_sheet(args: &ContactSheetArgs) -> Result<(), CliError> {
    let (options, appearance) = args.look.options(args.seed);
    let sheet = contact_sheet(&TaskId::ALL, args.seed, options, appearance)?;
    write_png_file(&args.out, sheet.width_px, sheet.height_px, 3, &sheet.rgb)?;
    say!(
        "wrote {} ({}x{}): columns {}; rows RGB, depth, mask",
        args.out.display(),
        sheet.width_px,
        sheet.height_px,
        TaskId::ALL.map(|t| t.code()).join(", ")
    );
    Ok(())
}

#[derive(clap::Args, Debug)]
struct RecordArgs {
    /// Task name (gauze_pick, ...) or id (T1-1, ...).
    #[arg(long)]
    task: TaskId,
    /// Episode seed: decides the spawn positions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The MCAP file to write (must not exist).
    #[arg(long)]
    out: PathBuf,
}

fn run_record(args: &RecordArgs) -> Result<(), CliError> {
    if args.out.exists() {
        return Err(CliError::usage(format!(
            "{} already exists; remove it or choose another path",
            args.out.display()
        )));
    }
    let library = ExpertLibrary::builtin()?;
    let options = surgvla::collect::record::RecordOptions::default();
    let collect = surgvla::collect::run::CollectOptions {
        tasks: vec![args.task],
        episodes_per_task: 1,
        seed: args.seed,
        ..Default::default()
    };
    let features = surgvla::episode::FeatureSet {
        mask: true,
        ..Default::default()
    };
    let info = surgvla::collect::run::dataset_info(&collect, features, &library);
    let (episode, bytes) =
        surgvla::collect::record::record_mcap(&library, args.task, args.seed, &options, &info)
            .map_err(|e| {
                use surgvla::collect::record::{RecordError, RecordMcapError};
                match e {
                    RecordMcapError::Export(e) => CliError::from(e),
                    RecordMcapError::Record(RecordError::Plan(e)) => CliError::from(e),
                    RecordMcapError::Record(RecordError::Spawn(e)) => CliError::from(e),
                }
            })?;
    surgvla::export::write_atomically(&args.out, &bytes)
        .map_err(|e| CliError::from(e).context(format!("writing {}", args.out.display())))?;
    say!(
        "{} ({}), seed {}: {} steps, {}; wrote {} ({:.1} MB)",
        args.task.code(),
        args.task.name(),
        args.seed,
        episode.steps.len(),
        if episode.meta.success {
            "success"
        } else {
            "failure"
        },
        args.out.display(),
        bytes.len() as f64 / 1e6
    );
    Ok(())
}

#[derive(clap::Args, Debug)]
struct SimArgs {
    /// Task name (gauze_pick, ...) or id (T1-1, ...).
    #[arg(long, default_value = "gauze_pick")]
    task: TaskId,
    /// Episode seed: decides the spawn positions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Most control steps to run (5 per simulated second).
    #[arg(long, default_value_t = 150, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    steps: u32,
}

fn run_sim(args: &SimArgs) -> Result<(), CliError> {
    let instance = args
        .task
        .instance(args.seed, &surgvla::task::TaskConfig::default())?;
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let library = ExpertLibrary::builtin()?;
    let mut policy = library
        .plan(args.task)?
        .expert(&instance, &sim.observation(), args.seed)?;
    let trajectory = rollout(&mut sim, &mut policy, args.steps);
    say!(
        "task {} ({}), seed {}, instruction \"{}\"",
        args.task.code(),
        args.task.name(),
        args.seed,
        instance.instruction
    );
    let object_name = sim.scene().objects.first().map(|o| o.name.clone());
    say!(
        "{:>4} {:>7} {:>7} {:>7} {:>7} {:>6}  {:>6} {:<7} {:>8} {:>8}",
        "step",
        "t_s",
        "x_mm",
        "y_mm",
        "z_mm",
        "yaw_d",
        "jaw_d",
        "bound",
        "obj_z_mm",
        "event"
    );
    let all = trajectory
        .steps
        .iter()
        .map(|s| (&s.observation, Some(s.report)));
    let last = std::iter::once((&trajectory.final_observation, None));
    let mut previous_report = None;
    for (observation, report) in all.chain(last) {
        let [x, y, z] = observation.tip_position_m;
        let object = object_name
            .as_deref()
            .and_then(|name| observation.object(name));
        let event = match previous_report {
            Some(surgvla::sim::StepReport { bound: Some(_), .. }) => "grasp",
            Some(surgvla::sim::StepReport {
                released: Some(_), ..
            }) => "release",
            _ => "",
        };
        say!(
            "{:>4} {:>7.1} {:>7.2} {:>7.2} {:>7.2} {:>6.1}  {:>6.1} {:<7} {:>8} {:>8}",
            observation.step_index,
            observation.time_secs,
            x * 1e3,
            y * 1e3,
            z * 1e3,
            observation.tip_euler_xyz_rad[2].to_degrees(),
            observation.jaw_angle_rad.to_degrees(),
            object.map_or("-", |o| if o.bound { o.name.as_str() } else { "-" }),
            object.map_or("-".to_string(), |o| format!(
                "{:.2}",
                o.world_from_object.translation.z * 1e3
            )),
            event
        );
        previous_report = report;
    }
    say!("trajectory digest {:016x}", trajectory.digest());
    let verdict = instance.success(&trajectory.final_observation);
    say!(
        "{}: {}",
        if verdict.success {
            "success"
        } else {
            "failure"
        },
        verdict.reason
    );
    Ok(())
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
        Command::Sim(args) => run_sim(&args),
        Command::Render(args) => run_render(&args),
        Command::ContactSheet(args) => run_contact_sheet(&args),
        Command::Collect(args) => episodes::run_collect(&args),
        Command::Convert(args) => formats::run_convert(&args),
        Command::Record(args) => run_record(&args),
        Command::Experts(args) => episodes::run_experts(&args),
        Command::Merge(args) => formats::run_merge(&args),
        Command::Eval(args) => eval::run_eval(&args),
        Command::Report(args) => eval::run_report(&args),
        Command::Validate(args) => inspect::run_validate(&args),
        Command::Info(args) => inspect::run_info(&args),
        Command::Schema { with_mask, format } => run_schema(with_mask, format),
        Command::Tasks => run_tasks(),
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

fn run_schema(with_mask: bool, format: SchemaFormat) -> Result<(), CliError> {
    let set = surgvla::episode::FeatureSet {
        mask: with_mask,
        ..Default::default()
    };
    let options = surgvla::collect::run::CollectOptions::default();
    let info = surgvla::collect::run::dataset_info(&options, set, &ExpertLibrary::builtin()?);
    let json = format
        .0
        .schema(&info)
        .ok_or_else(|| CliError::usage(format!("{} has no features schema", format.0.name())))?;
    say!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

fn run_tasks() -> Result<(), CliError> {
    for task in TaskId::ALL {
        say!(
            "{}  L{}  {:<24} {:>3} steps  \"{}\"",
            task.code(),
            task.level(),
            task.name(),
            task.step_limit(),
            task.instruction()
        );
        for paraphrase in task.paraphrases() {
            say!("{:>41}  or \"{paraphrase}\"", "");
        }
    }
    Ok(())
}
