//! Small light objects rest stably: they settle quickly, stay put, and never tunnel.

use crate::util::{simulator, three_objects};
use surgvla::scene::TRAY_TOP_Z_M;
use surgvla::sim::{NativeCommand, Simulator};

fn idle(sim: &mut Simulator, steps: u32) {
    for _ in 0..steps {
        sim.step_native(&NativeCommand {
            jaw: 1.0,
            ..NativeCommand::default()
        });
    }
}

fn positions(sim: &Simulator) -> Vec<[f64; 3]> {
    sim.observation()
        .objects
        .iter()
        .map(|o| o.world_from_object.translation.vector.into())
        .collect()
}

#[test]
fn objects_dropped_from_3cm_settle_within_1s_and_stay_within_0_1mm() {
    let scene = three_objects(0.03);
    let mut sim = simulator(scene.clone());
    idle(&mut sim, 5); // 1 s at 5 Hz
    let settled = positions(&sim);
    let observation = sim.observation();
    for (object, spec) in observation.objects.iter().zip(scene.objects.iter()) {
        let rest_z = TRAY_TOP_Z_M + spec.kind.rest_height_m();
        let z = object.world_from_object.translation.z;
        assert!(
            (z - rest_z).abs() < 3e-4,
            "{} rests at {z}, expected {rest_z}",
            object.name
        );
        assert!(object.on_tray, "{} not on the tray", object.name);
        let tilt = object
            .world_from_object
            .rotation
            .angle_to(&spec.world_from_object.rotation);
        assert!(tilt < 0.05, "{} tilted by {tilt} rad", object.name);
    }
    let mut worst_m = 0.0f64;
    for _ in 0..25 {
        idle(&mut sim, 1);
        for (now, then) in positions(&sim).iter().zip(settled.iter()) {
            let d = ((now[0] - then[0]).powi(2)
                + (now[1] - then[1]).powi(2)
                + (now[2] - then[2]).powi(2))
            .sqrt();
            worst_m = worst_m.max(d);
        }
    }
    assert!(worst_m < 1e-4, "drifted {worst_m} m after settling");
}

#[test]
fn a_fast_drop_does_not_tunnel_through_the_tray() {
    // 20 cm above the tray: about 2 m/s at impact, ~8 mm per 240 Hz step, more than the gauze
    // and needle are thick.
    let mut sim = simulator(three_objects(0.2));
    idle(&mut sim, 10);
    for object in sim.observation().objects {
        let z = object.world_from_object.translation.z;
        assert!(
            z > TRAY_TOP_Z_M,
            "{} fell through the tray (z = {z})",
            object.name
        );
        assert!(
            z < TRAY_TOP_Z_M + 0.005,
            "{} did not come to rest (z = {z})",
            object.name
        );
    }
}

#[test]
fn workspace_clips_every_command() {
    use surgvla::policy::{Policy, RandomPolicy};
    let mut sim = simulator(three_objects(0.0));
    let workspace = sim.config().workspace;
    let mut policy = RandomPolicy::new(9);
    for step in 0..150 {
        let mut command = policy.act(&sim.observation());
        // Push hard against a face of the box for a while, then wander.
        if step < 40 {
            command.dx = 1.0;
            command.dz = -1.0;
        }
        let report = sim.step_native(&command);
        let p = nalgebra::Vector3::from(sim.observation().tip_position_m);
        assert!(
            workspace.contains(&p, 1e-9),
            "step {step}: tip {p:?} left the workspace"
        );
        if step == 20 {
            assert!(report.clipped, "pushing past the box must report clipping");
        }
    }
}
