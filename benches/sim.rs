//! Criterion benches of the simulator.
//!
//! `sim/step`: one control step (48 physics substeps at 240 Hz) in a scene with a gauze, a
//! needle and a block, the instrument moving back and forth with the jaws opening and closing.
//! `sim/step_carrying`: the same with the gauze bound to the jaws (a kinematic body moving
//! among the others). `sim/ik`: one inverse-kinematics solve. `sim/trial_step` and
//! `sim/trial_step_with_progress`: one control step of T3-2 (hemostasis: the longest stage
//! chain, and an organ to count contacts with) without and with `eval`'s per-trial metrics
//! (`ProgressTracker::update`), side by side: what the metrics add to a trial;
//! `sim/progress_update`: the metrics' update alone.

// Tests and benches fail by unwrapping, expecting and panicking (denied in the library).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Isometry3;
use std::hint::black_box;
use surgvla::sim::psm::{Psm, pointing_down};
use surgvla::sim::{NativeCommand, SceneSpec, SimConfig, Simulator};

fn three_object_scene() -> SceneSpec {
    SceneSpec::one_of_each(0.0)
}

fn bench_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("sim");
    group.bench_function("step", |b| {
        let mut sim = Simulator::new(SimConfig::default(), three_object_scene());
        let mut i = 0u32;
        b.iter(|| {
            i = i.wrapping_add(1);
            let sign = if (i / 4).is_multiple_of(2) { 1.0 } else { -1.0 };
            let jaw = if (i / 3).is_multiple_of(2) { 1.0 } else { -1.0 };
            let command = NativeCommand {
                dx: 0.5 * sign,
                dy: 0.3 * sign,
                dz: 0.2 * sign,
                dyaw: 0.1 * sign,
                jaw,
            };
            black_box(sim.step_native(&command))
        });
    });
    group.bench_function("step_carrying", |b| {
        let mut sim = Simulator::new(SimConfig::default(), three_object_scene());
        let gauze = sim
            .above_object(0, 0.001, std::f64::consts::FRAC_PI_2)
            .expect("gauze");
        sim.teleport_tip(&gauze);
        sim.step_native(&NativeCommand {
            jaw: -1.0,
            ..NativeCommand::default()
        });
        assert_eq!(sim.bound_object(), Some(0));
        let mut i = 0u32;
        b.iter(|| {
            i = i.wrapping_add(1);
            let sign = if (i / 4).is_multiple_of(2) { 1.0 } else { -1.0 };
            black_box(sim.step_native(&NativeCommand {
                dx: 0.3 * sign,
                dz: 0.5 * sign,
                jaw: -1.0,
                ..NativeCommand::default()
            }))
        });
    });
    group.bench_function("ik", |b| {
        let psm = Psm::reference();
        let target = Isometry3::from_parts(
            nalgebra::Translation3::new(0.55, 0.01, 0.70),
            pointing_down(0.3),
        );
        b.iter(|| black_box(psm.inverse(black_box(&target), 0.0)));
    });
    group.finish();
}

/// What `eval`'s per-trial metrics add to a control step, side by side.
fn bench_progress(c: &mut Criterion) {
    let mut group = c.benchmark_group("sim");
    for with_progress in [false, true] {
        let name = if with_progress {
            "trial_step_with_progress"
        } else {
            "trial_step"
        };
        group.bench_function(name, |b| {
            let task = surgvla::task::TaskId::Hemostasis;
            let instance = task.instance(0, &Default::default()).unwrap();
            let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
            let mut tracker =
                surgvla::eval::progress::ProgressTracker::new(&instance, &sim.observation());
            let mut i = 0u32;
            b.iter(|| {
                i = i.wrapping_add(1);
                let sign = if (i / 4).is_multiple_of(2) { 1.0 } else { -1.0 };
                sim.step_native(&NativeCommand {
                    dx: 0.3 * sign,
                    dz: 0.2 * sign,
                    jaw: if (i / 3).is_multiple_of(2) { 1.0 } else { -1.0 },
                    ..NativeCommand::default()
                });
                let observation = sim.observation();
                if with_progress {
                    tracker.update(&observation);
                }
                black_box(observation)
            });
        });
    }
    group.bench_function("progress_update", |b| {
        let task = surgvla::task::TaskId::Hemostasis;
        let instance = task.instance(0, &Default::default()).unwrap();
        let sim = Simulator::new(SimConfig::default(), instance.scene.clone());
        let observation = sim.observation();
        let mut tracker = surgvla::eval::progress::ProgressTracker::new(&instance, &observation);
        b.iter(|| tracker.update(black_box(&observation)));
    });
    group.finish();
}

criterion_group!(benches, bench_step, bench_progress);
criterion_main!(benches);
