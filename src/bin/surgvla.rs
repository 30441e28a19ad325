//! The `surgvla` command line: parses arguments, calls the library, prints, and maps errors to
//! exit codes (2 for user mistakes, 1 for internal failures).

use clap::{Parser, Subcommand};
use std::process::ExitCode;
use surgvla::collect::{demo_plan, rollout};
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;

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
    /// Run the demo motion (grasp the first object, lift, release) in a task scene and print
    /// the trajectory.
    Sim(SimArgs),
    /// List the tasks.
    Tasks,
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
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    steps: u32,
}

fn run_sim(args: &SimArgs) {
    let scene = args.task.scene(args.seed);
    let mut sim = Simulator::new(SimConfig::default(), scene);
    let mut policy = demo_plan(&sim);
    let trajectory = rollout(&mut sim, &mut policy, args.steps);
    println!(
        "task {} ({}), seed {}, instruction \"{}\"",
        args.task.code(),
        args.task.name(),
        args.seed,
        args.task.instruction()
    );
    let object_name = sim.scene().objects.first().map(|o| o.name.clone());
    println!(
        "{:>4} {:>7} {:>7} {:>7} {:>7} {:>6}  {:>6} {:<7} {:>8} {:>8}",
        "step", "t_s", "x_mm", "y_mm", "z_mm", "yaw_d", "jaw_d", "bound", "obj_z_mm", "event"
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
        println!(
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
    println!("trajectory digest {:016x}", trajectory.digest());
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
    match cli.command {
        Command::Sim(args) => run_sim(&args),
        Command::Tasks => {
            for task in TaskId::ALL {
                println!(
                    "{}  L{}  {:<24} {:>3} steps  \"{}\"",
                    task.code(),
                    task.level(),
                    task.name(),
                    task.step_limit(),
                    task.instruction()
                );
            }
        }
    }
    ExitCode::SUCCESS
}
