//! `surgvla sim`: a task's scripted expert run in a scene, its trajectory and verdict printed.

use crate::error::CliError;
use surgvla::collect::rollout;
use surgvla::policy::ExpertLibrary;
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;

#[derive(clap::Args, Debug)]
pub(crate) struct SimArgs {
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

pub(crate) fn run_sim(args: &SimArgs) -> Result<(), CliError> {
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
