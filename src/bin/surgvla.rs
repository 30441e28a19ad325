//! The `surgvla` command line: parses arguments, calls the library, prints, and maps errors to
//! exit codes (2 for user mistakes, 1 for internal failures).

/// Writes a line to stdout; a failed write (a closed pipe) returns an error with `?`, which
/// `main` treats as a quiet exit when the pipe was closed.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($arg)*)?
    }};
}

mod progress;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use surgvla::assets::{Appearance, SceneAssets};
use surgvla::collect::rollout;
use surgvla::collect::run::Shard;
use surgvla::policy::ExpertLibrary;
use surgvla::render::image::{ImageError, depth_visualisation, mask_visualisation, write_png_file};
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
    /// Record verified expert episodes of the tasks and write a LeRobot dataset (defaults: all
    /// eight tasks, 100 episodes each, into ./data).
    Collect(CollectArgs),
    /// Print the LeRobot features schema (what schemas/lerobot_features.json records).
    Schema {
        /// Include the segmentation mask feature.
        #[arg(long)]
        with_mask: bool,
    },
    /// List the tasks: id, level, name, step limit, canonical instruction and paraphrases.
    Tasks,
}

#[derive(clap::Args, Debug)]
struct CollectArgs {
    /// Tasks: "all" or a comma-separated list of names or ids.
    #[arg(long, default_value = "all")]
    tasks: String,
    /// Verified episodes per task.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    episodes_per_task: u64,
    /// Collection seed: every episode's seed derives from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output folder (must not exist or be empty).
    #[arg(long, default_value = "data")]
    out: PathBuf,
    /// Output format (RLDS and point clouds are separate exporters, still to come).
    #[arg(long, default_value = "lerobot", value_parser = ["lerobot"])]
    format: String,
    /// Also store the segmentation mask as an image feature.
    #[arg(long)]
    with_mask: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Store the endoscope RGB as MP4 video (LeRobot video mode) instead of PNG: av1 (rav1e,
    /// LeRobot's codec family) or h264 (openh264, faster). `--video` alone means av1.
    #[arg(long, num_args = 0..=1, default_missing_value = "av1", value_parser = ["av1", "h264"])]
    video: Option<String>,
    /// This machine's part of the episode list, I/N (0-based): N machines with I = 0..N-1 each
    /// write the I-th contiguous range of episodes as their own dataset.
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// Continue an interrupted run in --out (same options and seed): episodes up to its last
    /// checkpoint are kept, the rest are recorded again.
    #[arg(long)]
    resume: bool,
    /// LeRobot layout: 3.0 (current) or 2.1 (one file per episode, JSON-lines metadata).
    #[arg(long, default_value = "3.0", value_parser = ["3.0", "2.1"])]
    lerobot_version: String,
    /// action[6]: "continuous" (1 while commanded open, 0 while closed) or "pulse" (+1/-1 on
    /// the step the command changes, 0 otherwise; for ablations).
    #[arg(long, default_value = "continuous", value_parser = ["continuous", "pulse"])]
    gripper_encoding: String,
    /// Distractors in the level-2 pick tasks (T2-1, T2-2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=3))]
    distractors: u64,
    /// Instruction per episode: the canonical one, a seeded paraphrase, or a seeded mix.
    #[arg(long, default_value = "canonical", value_parser = ["canonical", "paraphrase", "mixed"])]
    instructions: String,
    /// Multiplies every spawn range's half width (3 gives the needle's evaluation range).
    #[arg(long, default_value_t = 1.0)]
    spawn_scale: f64,
    /// A folder of expert plans (*.toml) replacing the built-in scripted_policies/ per task.
    #[arg(long)]
    policies: Option<PathBuf>,
    /// Randomise light, tissue colour and texture contrast per episode.
    #[arg(long)]
    randomize_appearance: bool,
    /// Size at which a data file is closed and a new one begun, MB (LeRobot's
    /// data_files_size_in_mb); each closed file is also a resume checkpoint.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    data_file_mb: u64,
    /// Attempts per episode before the collection gives up.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=1000))]
    max_attempts: u32,
}

fn parse_tasks(text: &str) -> anyhow::Result<Vec<TaskId>> {
    if text.trim() == "all" {
        return Ok(TaskId::ALL.to_vec());
    }
    text.split(',')
        .map(|t| t.parse::<TaskId>().map_err(anyhow::Error::from))
        .collect()
}

fn run_collect(args: &CollectArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use surgvla::collect::run::{CollectOptions, collect};
    use surgvla::episode::GripperEncoding;
    use surgvla::export::lerobot::{LeRobotOptions, LeRobotVersion, LeRobotWriter, VideoOptions};
    use surgvla::task::{InstructionChoice, TaskConfig};
    let usage = |message: String| anyhow::Error::new(UsageError(message));
    let tasks = parse_tasks(&args.tasks).map_err(|e| usage(e.to_string()))?;
    if !(args.spawn_scale.is_finite() && (0.0..=5.0).contains(&args.spawn_scale)) {
        return Err(usage(format!(
            "--spawn-scale {} must be between 0 and 5",
            args.spawn_scale
        )));
    }
    let library = match &args.policies {
        Some(folder) => ExpertLibrary::with_folder(folder),
        None => ExpertLibrary::builtin(),
    }
    .map_err(|e| usage(e.to_string()))?;
    let gripper = if args.gripper_encoding == "pulse" {
        GripperEncoding::Pulse
    } else {
        GripperEncoding::Continuous
    };
    let task_config = TaskConfig {
        distractors: args.distractors as usize,
        instruction: match args.instructions.as_str() {
            "paraphrase" => InstructionChoice::Paraphrase,
            "mixed" => InstructionChoice::Mixed,
            _ => InstructionChoice::Canonical,
        },
        spawn_scale: args.spawn_scale,
        ..TaskConfig::default()
    };
    let options = CollectOptions {
        tasks,
        episodes_per_task: args.episodes_per_task,
        seed: args.seed,
        shard: args.shard,
        threads: args.threads.unwrap_or(0),
        max_attempts: args.max_attempts,
        record: surgvla::collect::record::RecordOptions {
            randomize_appearance: args.randomize_appearance,
            gripper,
            task: task_config,
            ..Default::default()
        },
    };
    let mut metadata = surgvla::view::dataset_metadata(&Camera::endoscope());
    metadata["collection"] = serde_json::json!({
        "seed": args.seed,
        "tasks": options.tasks.iter().map(|t| t.code()).collect::<Vec<_>>(),
        "episodes_per_task": args.episodes_per_task,
        "shard": args.shard.to_string(),
        "gripper_encoding": gripper,
        "distractors": args.distractors,
        "instructions": args.instructions,
        "spawn_scale": args.spawn_scale,
        "randomize_appearance": args.randomize_appearance,
        "policies": if args.policies.is_some() { "custom" } else { "builtin" },
    });
    let writer_options = LeRobotOptions {
        with_mask: args.with_mask,
        extra_metadata: metadata,
        video: args.video.as_deref().map(|codec| match codec {
            "h264" => VideoOptions::h264(),
            _ => VideoOptions::default(),
        }),
        version: if args.lerobot_version == "2.1" {
            LeRobotVersion::V21
        } else {
            LeRobotVersion::V30
        },
        data_file_size_mb: args.data_file_mb,
        ..LeRobotOptions::default()
    };
    let interrupted = args
        .out
        .join(surgvla::export::lerobot::INCOMPLETE_MARKER)
        .exists();
    let (writer, resume_at) = if args.resume && interrupted {
        let writer = LeRobotWriter::resume(&args.out, writer_options)?;
        let next = writer.next_episode_index();
        eprintln!("resuming {} at episode {next}", args.out.display());
        (writer, next as usize)
    } else {
        (LeRobotWriter::create(&args.out, writer_options)?, 0)
    };
    let mut bars = progress::Bars::new(&options.tasks);
    let report = collect(&options, &library, Box::new(writer), resume_at, &mut bars)?;
    bars.clear();
    let path = args.out.join("collect_report.json");
    let json = serde_json::to_string_pretty(&report)?;
    surgvla::export::write_atomically(&path, json.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    progress::print_summary(&report)?;
    say!(
        "wrote {} episodes, {} frames to {} ({} files, {:.1} MB); report {}",
        report.dataset.episodes,
        report.dataset.frames,
        args.out.display(),
        report.dataset.files,
        report.dataset.bytes as f64 / 1e6,
        path.display()
    );
    Ok(())
}

/// A mistake in the command line found after parsing (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct UsageError(String);

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
        };
        (options, appearance)
    }
}

fn run_render(args: &RenderArgs) -> anyhow::Result<()> {
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

fn run_contact_sheet(args: &ContactSheetArgs) -> anyhow::Result<()> {
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

fn run_sim(args: &SimArgs) -> anyhow::Result<()> {
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(error) => {
            let code = if error.use_stderr() { 2 } else { 0 };
            let _ = error.print();
            return ExitCode::from(code);
        }
    };
    let result = match cli.command {
        Command::Sim(args) => run_sim(&args),
        Command::Render(args) => run_render(&args),
        Command::ContactSheet(args) => run_contact_sheet(&args),
        Command::Collect(args) => run_collect(&args),
        Command::Schema { with_mask } => run_schema(with_mask),
        Command::Tasks => run_tasks(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // Output piped into a reader that stopped (`surgvla tasks | head`): not an error.
        Err(error)
            if error.chain().any(|cause| {
                cause
                    .downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) =>
        {
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::from(exit_code(&error))
        }
    }
}

fn run_schema(with_mask: bool) -> anyhow::Result<()> {
    let features = surgvla::episode::standard_features(224, 224, with_mask);
    let json = surgvla::export::lerobot::features_json(&features);
    say!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

fn run_tasks() -> anyhow::Result<()> {
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

/// 2 when the user can fix it (an output path in a missing or forbidden place), 1 otherwise.
fn exit_code(error: &anyhow::Error) -> u8 {
    use std::io::ErrorKind;
    use surgvla::export::ExportError;
    let user_fixable = |kind: ErrorKind| {
        matches!(
            kind,
            ErrorKind::NotFound | ErrorKind::PermissionDenied | ErrorKind::IsADirectory
        )
    };
    let fixable = error.chain().any(|cause| {
        if cause.is::<UsageError>() {
            return true;
        }
        match (
            cause.downcast_ref::<ImageError>(),
            cause.downcast_ref::<ExportError>(),
        ) {
            (Some(ImageError::Io { source, .. }), _) => user_fixable(source.kind()),
            (_, Some(ExportError::NotEmpty { .. } | ExportError::NotResumable { .. })) => true,
            (_, Some(ExportError::Io { source, .. })) => user_fixable(source.kind()),
            _ => cause
                .downcast_ref::<std::io::Error>()
                .is_some_and(|io| user_fixable(io.kind())),
        }
    });
    if fixable { 2 } else { 1 }
}
