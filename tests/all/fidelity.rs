//! Every success predicate can fail, and fails for what a surgeon would not accept: a clip that
//! arrives closed, closes on top of the vessel or beside it; a touch hovering over the spot or
//! pushed into the organ; a gauze placed beside the block, dropped from high above its support,
//! or leaving the hemostasis spot uncovered; a needle dragged along the tray; and a held object
//! never sinks into the pad. (The grasp rule's cases are in `grasping.rs`, the distractors' in
//! `tasks.rs`.)

use surgvla::collect::record::{attempt_seed, run_expert};
use surgvla::collect::rollout;
use surgvla::episode::GripperEncoding;
use surgvla::policy::plan::ExpertPlan;
use surgvla::scene::{GAUZE_HALF_EXTENTS_M, TRAY_TOP_Z_M};
use surgvla::sim::{HELD_PENETRATION_M, SimConfig, Simulator};
use surgvla::task::{TaskConfig, TaskId, TaskInstance};

fn builtin(task: TaskId) -> String {
    let path = format!(
        "{}/scripted_policies/{}.toml",
        env!("CARGO_MANIFEST_DIR"),
        task.name()
    );
    std::fs::read_to_string(path).expect("plan")
}

fn plan(text: &str) -> ExpertPlan {
    ExpertPlan::parse(text, std::path::Path::new("edited.toml")).expect("a valid plan")
}

fn instance(task: TaskId, k: u64) -> TaskInstance {
    task.instance(attempt_seed(5, task, k, 0), &TaskConfig::default())
        .expect("scene")
}

/// Runs `text` as the expert of `task` on a few slots: every verdict fails, saying `why`.
fn always_fails(task: TaskId, text: &str, why: &str) {
    always_fails_for_one_of(task, text, &[why]);
}

/// Runs `text` as the expert of `task` on a few slots: every verdict fails, saying one of
/// `whys` (a motion that breaks two rules fails on whichever it breaks first).
fn always_fails_for_one_of(task: TaskId, text: &str, whys: &[&str]) {
    let plan = plan(text);
    for k in 0..4 {
        let run = run_expert(
            &instance(task, k),
            &plan,
            task.step_limit(),
            GripperEncoding::Continuous,
        )
        .expect("run");
        assert!(!run.verdict.success, "{task} k {k}: {}", run.verdict.reason);
        assert!(
            whys.iter().any(|why| run.verdict.reason.contains(why)),
            "{task} k {k}: {}",
            run.verdict.reason
        );
    }
}

#[test]
fn a_clip_must_arrive_open_and_straddle_the_vessel() {
    let task = TaskId::VesselClipping;
    let expert = builtin(task);
    // The built-in expert clips (checked on every task elsewhere); these must not.
    // Closed from 25 mm above and pushed down onto the vessel: the jaws were closed when the
    // tip entered the band around it.
    let touch = expert.replace("jaw = \"open\"", "jaw = \"close\"");
    always_fails(task, &touch, "a clip closes around it");
    let on_top = expert.replace("-0.0035", "0.0");
    always_fails(task, &on_top, "do not straddle");
    // Beside the vessel: the tip 3.5 mm off its axis (the vessel runs along x, within 30 deg),
    // outside its 2.5 mm radius.
    let beside = expert.replace(
        "frame = \"mark\"\noffset_m = [0.0, 0.0, -0.0035]",
        "frame = \"mark\"\noffset_m = [0.0, 0.0035, -0.0035]",
    );
    assert_ne!(beside, expert);
    always_fails_for_one_of(
        task,
        &beside,
        &["from the vessel's axis", "through the vessel's wall"],
    );
}

/// A simulator of `instance`'s scene whose jaws have closed (on nothing) at the start pose.
fn closed_jaws(instance: &TaskInstance) -> Simulator {
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    sim.step_native(&surgvla::sim::NativeCommand {
        jaw: -1.0,
        ..Default::default()
    });
    sim
}

/// The loophole as it was found: closed jaws 3.5 mm over the spot, or 3.5 mm into the kidney
/// under it, were within the old 4 mm sphere; on the spot itself they touch.
#[test]
fn closed_jaws_3_5_mm_over_or_into_the_kidney_do_not_touch_it() {
    let task = TaskId::Electrocoagulation;
    for k in 0..4 {
        let instance = instance(task, k);
        let spot = instance.scene.marks[instance.target_mark.expect("spot")].position_m;
        let verdict_at = |dz: f64| {
            let mut sim = closed_jaws(&instance);
            let mut pose = sim.world_from_tip();
            pose.translation.vector = spot + nalgebra::Vector3::new(0.0, 0.0, dz);
            assert!(sim.teleport_tip(&pose).is_exact());
            instance.success(&sim.observation())
        };
        let on = verdict_at(0.0);
        assert!(on.success, "k {k}: {}", on.reason);
        for dz in [0.0035, -0.0035] {
            let verdict = verdict_at(dz);
            assert!(!verdict.success, "k {k} dz {dz}: {}", verdict.reason);
            // Over it: not on the surface; into it: a stab (more than 2 mm deep).
            let why = if dz > 0.0 {
                "tissue's surface"
            } else {
                "into the tissue"
            };
            assert!(verdict.reason.contains(why), "{}", verdict.reason);
        }
    }
}

/// A stab is remembered: closed jaws pushed 6 mm into the kidney and pulled back onto the spot
/// fail, though the end state is a touch; a touch pressed 1.5 mm into the tissue (within the
/// 2 mm allowed) and eased back onto the spot passes. The peak is measured along the ray from
/// the organ's centre.
#[test]
fn a_stab_pulled_back_onto_the_spot_is_a_failure_a_firm_press_is_not() {
    let task = TaskId::Electrocoagulation;
    for k in 0..3 {
        let instance = instance(task, k);
        let spot = instance.scene.marks[instance.target_mark.expect("spot")].position_m;
        for (deepest, honest) in [(-0.006, false), (-0.0015, true)] {
            let mut sim = closed_jaws(&instance);
            let mut visit = |dz: f64| {
                let mut pose = sim.world_from_tip();
                pose.translation.vector = spot + nalgebra::Vector3::new(0.0, 0.0, dz);
                assert!(sim.teleport_tip(&pose).is_exact());
                let observation = sim.observation();
                (observation.history.peak_penetration_m, observation)
            };
            assert!(visit(0.0).0 <= 0.001, "k {k}");
            let (peak, _) = visit(deepest);
            assert!(
                (-deepest - 0.0005..-2.0 * deepest).contains(&peak),
                "k {k}: {peak} m"
            );
            // Back on the spot: the end state is a touch; the peak is not forgotten.
            let (after, observation) = visit(0.0);
            assert_eq!(after, peak);
            let verdict = instance.success(&observation);
            assert_eq!(verdict.success, honest, "k {k}: {}", verdict.reason);
            assert_eq!(
                instance.terminal_failure(&observation).is_some(),
                !honest,
                "k {k}"
            );
            if !honest {
                assert!(
                    verdict.reason.contains("into the tissue"),
                    "{}",
                    verdict.reason
                );
            }
        }
    }
}

#[test]
fn a_touch_is_on_the_tissue_not_over_it_or_inside_it() {
    let task = TaskId::Electrocoagulation;
    let expert = builtin(task);
    let touch = "name = \"touch\"\nframe = \"mark\"\noffset_m = [0.0, 0.0, 0.0]";
    assert!(expert.contains(touch));
    let hovering = expert.replace(touch, &touch.replace("0.0]", "0.0025]"));
    always_fails(task, &hovering, "above the tissue's surface");
    // 2.5 mm in: a stab (more than 2 mm); 2.1 mm down (1-2 mm into the curved surface), held:
    // not on the surface.
    let pushed_in = expert.replace(touch, &touch.replace("0.0]", "-0.0025]"));
    always_fails(task, &pushed_in, "into the tissue");
    let pressed = expert.replace(touch, &touch.replace("0.0]", "-0.0021]"));
    always_fails(task, &pressed, "inside the tissue's surface");
}

#[test]
fn a_gauze_let_go_high_above_its_support_is_not_placed() {
    for (task, height) in [
        (TaskId::PickAndPlace, "0.0035"),
        (TaskId::Hemostasis, "0.005"),
    ] {
        let expert = builtin(task);
        let low = format!("frame = \"place\"\noffset_m = [0.0, 0.0, {height}]");
        assert!(expert.contains(&low), "{task}");
        // Lowered to 40 mm above the target only, and opened there.
        let dropped = expert.replace(&low, "frame = \"place\"\noffset_m = [0.0, 0.0, 0.04]");
        always_fails(task, &dropped, "above its support");
    }
}

/// Slot `k` of `task` (T3-1, T3-2) and the observation after its built-in expert placed the
/// gauze (checked a success).
fn placed_by_the_expert(task: TaskId, k: u64) -> (TaskInstance, surgvla::sim::Observation) {
    let plan = plan(&builtin(task));
    let instance = instance(task, k);
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let mut expert = plan
        .expert(&instance, &sim.observation(), instance.seed)
        .expect("expert");
    let placed = rollout(&mut sim, &mut expert, 150).final_observation;
    let verdict = instance.success(&placed);
    assert!(verdict.success, "{task} k {k}: {}", verdict.reason);
    (instance, placed)
}

#[test]
fn a_hemostasis_gauze_must_cover_the_spot() {
    // The honest placement passes; the same gauze moved 9 mm along its short side after it was
    // let go (its centre still within the old 10 mm) leaves the spot uncovered; moved 2 mm
    // (a slide the spleen's flank allows) it still passes.
    let task = TaskId::Hemostasis;
    for k in 0..3 {
        let (instance, placed) = placed_by_the_expert(task, k);
        let gauze = instance.target_object.expect("gauze");
        let mut moved = placed.clone();
        let pose = &mut moved.objects[gauze].world_from_object;
        let short_side = pose.rotation * nalgebra::Vector3::x();
        let mark = &instance.scene.marks[instance.target_mark.expect("mark")];
        let from_mark = pose.translation.vector - mark.position_m;
        let sign = if from_mark.dot(&short_side) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let start = pose.translation.vector;
        pose.translation.vector = start + sign * 0.002 * short_side;
        let verdict = instance.success(&moved);
        assert!(verdict.success, "k {k}: {}", verdict.reason);
        moved.objects[gauze].world_from_object.translation.vector =
            start + sign * 0.009 * short_side;
        let verdict = instance.success(&moved);
        assert!(!verdict.success);
        assert!(verdict.reason.contains("slid off"), "{}", verdict.reason);
    }
}

#[test]
fn a_gauze_beside_the_block_or_15_mm_from_the_target_is_not_placed() {
    let beside = builtin(TaskId::PickAndPlace).replace(
        "frame = \"place\"\noffset_m = [0.0, 0.0,",
        "frame = \"place\"\noffset_m = [-0.02, 0.0,",
    );
    always_fails(TaskId::PickAndPlace, &beside, "not over the block");
    let off_target = builtin(TaskId::Hemostasis).replace(
        "frame = \"place\"\noffset_m = [0.0, 0.0,",
        "frame = \"place\"\noffset_m = [0.0, 0.015,",
    );
    // Let go 15 mm aside, where the spleen's flank falls away: not over the spot, or (lower
    // on the flank) dropped from above 5 mm.
    always_fails_for_one_of(
        TaskId::Hemostasis,
        &off_target,
        &["not under the gauze", "gauze dropped"],
    );
}

#[test]
fn a_needle_dragged_along_the_tray_is_not_picked() {
    // Grasp, then slide 20 mm sideways at grasp height instead of lifting.
    let dragged = builtin(TaskId::NeedlePick).replace(
        "offset_m = [0.0, 0.0, 0.03]",
        "offset_m = [0.02, 0.0, 0.0005]",
    );
    always_fails(TaskId::NeedlePick, &dragged, "needle");
    // And the "off the tray" test itself fails while the held needle lies on the tray.
    let instance = instance(TaskId::NeedlePick, 0);
    let plan = plan(&builtin(TaskId::NeedlePick));
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let mut expert = plan
        .expert(&instance, &sim.observation(), instance.seed)
        .expect("expert");
    let trajectory = rollout(&mut sim, &mut expert, 100);
    let held: Vec<_> = trajectory
        .steps
        .iter()
        .map(|s| &s.observation)
        .filter(|o| o.bound_object == Some(0))
        .collect();
    assert!(
        held.first().expect("grasped").objects[0].on_tray,
        "held on the tray"
    );
    assert!(
        !held.last().expect("lifted").objects[0].on_tray,
        "lifted off it"
    );
}

#[test]
fn a_held_gauze_pressed_into_the_pad_stops_at_its_surface() {
    // Close 5 mm below the grasp point: the jaws try to press the gauze into the pad.
    let pressed = builtin(TaskId::GauzePick).replace(
        "name = \"close\"\nframe = \"pick\"\noffset_m = [0.0, 0.0, 0.0005]",
        "name = \"close\"\nframe = \"pick\"\noffset_m = [0.0, 0.0, -0.005]",
    );
    assert_ne!(pressed, builtin(TaskId::GauzePick));
    let plan = plan(&pressed);
    for k in 0..4 {
        let instance = instance(TaskId::GauzePick, k);
        let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
        let mut expert = plan
            .expert(&instance, &sim.observation(), instance.seed)
            .expect("expert");
        let trajectory = rollout(&mut sim, &mut expert, 100);
        let mut held_steps = 0;
        for observation in trajectory.steps.iter().map(|s| &s.observation) {
            if observation.bound_object != Some(0) {
                continue;
            }
            held_steps += 1;
            let bottom =
                observation.objects[0].world_from_object.translation.z - GAUZE_HALF_EXTENTS_M[2];
            assert!(
                bottom >= TRAY_TOP_Z_M - HELD_PENETRATION_M - 1e-5,
                "k {k} step {}: the gauze's bottom is {:.2} mm into the pad",
                observation.step_index,
                (TRAY_TOP_Z_M - bottom) * 1e3
            );
            // The jaws stop at the gauze's thickness, not at zero.
            assert!(
                observation.jaw_angle_rad > 0.2,
                "{}",
                observation.jaw_angle_rad
            );
        }
        assert!(held_steps > 5, "k {k}: the gauze was held");
    }
}

/// The touch rule's radius is the drawn spot's: closed jaws on the tissue 2 mm from the spot's
/// centre touch it; 3.8 mm from it (1.4 mm outside the drawn 2.4 mm spot) they do not.
#[test]
fn a_touch_counts_on_the_drawn_spot_only() {
    let task = TaskId::Electrocoagulation;
    for k in 0..4 {
        let instance = instance(task, k);
        let mark = &instance.scene.marks[instance.target_mark.expect("spot")];
        assert_eq!(mark.radius_m, 0.0024);
        let organ = &instance.scene.organs[0];
        let verdict_at = |aside_m: f64| {
            // Along the surface: aside in y, then onto the surface along the ray from the
            // organ's centre.
            let centre = organ.world_from_organ.translation.vector;
            let ray =
                (mark.position_m + nalgebra::Vector3::new(0.0, aside_m, 0.0) - centre).normalize();
            let local = organ.world_from_organ.rotation.inverse() * ray;
            let surface = organ.world_from_organ
                * nalgebra::Point3::from(surgvla::scene::organ::surface_point(organ, local));
            let mut sim = closed_jaws(&instance);
            let mut pose = sim.world_from_tip();
            pose.translation.vector = surface.coords;
            assert!(sim.teleport_tip(&pose).is_exact());
            instance.success(&sim.observation())
        };
        let on = verdict_at(0.002);
        assert!(on.success, "k {k}: {}", on.reason);
        let off = verdict_at(0.0038);
        assert!(!off.success, "k {k}");
        assert!(off.reason.contains("off the drawn spot"), "{}", off.reason);
    }
}

/// A placement stands only while its support stays: the block carried 6 mm away after the gauze
/// was let go on it fails; nudged 1 mm it passes.
#[test]
fn a_block_moved_after_the_placement_undoes_it() {
    for k in 0..3 {
        let (instance, placed) = placed_by_the_expert(TaskId::PickAndPlace, k);
        let block = instance.support_object.expect("block");
        let gauze = instance.target_object.expect("gauze");
        for (moved_m, honest) in [(0.001, true), (0.006, false)] {
            let mut moved = placed.clone();
            for index in [block, gauze] {
                moved.objects[index].world_from_object.translation.vector.x += moved_m;
            }
            let verdict = instance.success(&moved);
            assert_eq!(verdict.success, honest, "k {k}: {}", verdict.reason);
            if !honest {
                assert!(
                    verdict.reason.contains("the block moved"),
                    "{}",
                    verdict.reason
                );
            }
        }
    }
}
