//! A trial's history is part of its verdict (rule set surgvla-physical-v2), tested in closed
//! loop through `Env::step` as `eval` runs a policy: for each class of motion a grader calls a
//! failure, the dishonest motion ends the trial the moment it happens, whatever follows, and an
//! honest neighbour passes. The motions are steered from the observed state, as a policy would
//! be, with actions inside the reference's action space.

use nalgebra::Vector3;
use surgvla::env::{Env, EnvOptions, EnvStep};
use surgvla::sim::PhysicalAction;
use surgvla::task::{TaskConfig, TaskId};

/// A headless environment of `task` and `seed` with room for several phases.
fn env(task: TaskId, seed: u64) -> Env {
    let options = EnvOptions {
        max_steps: Some(600),
        ..EnvOptions::headless()
    };
    let instance = task.instance(seed, &TaskConfig::default()).expect("spawn");
    Env::from_instance(instance, &options).0
}

/// Drives the tip to `target_m` (world) with yaw `yaw_rad` and the gripper at `gripper` (1 open,
/// 0 closed), at most `max_step_m` per axis and step; returns the last step, which is `done`
/// when the trial ended on the way (a trial already ended with success goes on: what a policy
/// does after it is tested too).
fn steer(
    env: &mut Env,
    target_m: Vector3<f64>,
    yaw_rad: f64,
    gripper: f64,
    max_step_m: f64,
) -> EnvStep {
    let succeeded = env.verdict().success;
    for _ in 0..200 {
        let state = env.sim_observation().state7();
        let tip = Vector3::new(state[0], state[1], state[2]);
        let delta = (target_m - tip).map(|v| v.clamp(-max_step_m, max_step_m));
        let dyaw = wrap(yaw_rad - state[5]);
        let step = env.step(&PhysicalAction::from_array([
            delta.x, delta.y, delta.z, 0.0, 0.0, dyaw, gripper,
        ]));
        let reached = (target_m - tip).amax() < 1e-5 && dyaw.abs() < 1e-4;
        if (step.done && !succeeded) || reached {
            return step;
        }
    }
    panic!("did not reach {target_m:?}");
}

/// Height over everything in the scene at which the tip moves between places, metres.
const TRANSIT_Z_M: f64 = 0.74;

/// Drives the tip up to [`TRANSIT_Z_M`], across above `target_m`, and down onto it, as a
/// policy moving between places does (never through an organ on the way).
fn transit(env: &mut Env, target_m: Vector3<f64>, yaw_rad: f64, gripper: f64) -> EnvStep {
    let state = env.sim_observation().state7();
    let high = TRANSIT_Z_M.max(state[2]);
    steer(
        env,
        Vector3::new(state[0], state[1], high),
        state[5],
        gripper,
        0.01,
    );
    steer(
        env,
        Vector3::new(target_m.x, target_m.y, high),
        yaw_rad,
        gripper,
        0.01,
    );
    steer(env, target_m, yaw_rad, gripper, 0.01)
}

/// Keeps the tip still with the gripper at `gripper` for `steps` steps.
fn hold(env: &mut Env, gripper: f64, steps: u32) -> EnvStep {
    let mut last = None;
    for _ in 0..steps {
        let step = env.step(&PhysicalAction::from_array([
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, gripper,
        ]));
        let done = step.done;
        last = Some(step);
        if done {
            break;
        }
    }
    last.expect("at least one step")
}

fn wrap(angle: f64) -> f64 {
    (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

const OPEN: f64 = 1.0;
const CLOSED: f64 = 0.0;

/// The end of a trial: done, failed, saying `why`.
fn ended_failing(step: &EnvStep, why: &str, what: &str) {
    assert!(
        step.done,
        "{what}: the trial goes on ({})",
        step.verdict.reason
    );
    assert!(!step.verdict.success, "{what}: {}", step.verdict.reason);
    assert!(
        step.verdict.reason.contains(why),
        "{what}: {}",
        step.verdict.reason
    );
}

fn ended_succeeding(step: &EnvStep, what: &str) {
    assert!(
        step.done && step.verdict.success,
        "{what}: {}",
        step.verdict.reason
    );
}

/// T2-3's named site, the vessel's direction there and the yaw whose jaws cross it.
fn clip_site(env: &Env) -> (Vector3<f64>, Vector3<f64>, f64) {
    let instance = env.instance();
    let mark = &instance.scene.marks[instance.target_mark.expect("site")];
    let along = mark.line_direction.expect("a vessel site");
    let along = Vector3::new(along.x, along.y, 0.0).normalize();
    let crossing_yaw = wrap(along.y.atan2(along.x) - std::f64::consts::FRAC_PI_2);
    (mark.position_m, along, crossing_yaw)
}

/// How far below the site (on the vessel's top) the expert closes: 1 mm below the centre line.
const CLIP_DEPTH_M: f64 = 0.0035;

#[test]
fn a_clip_counts_only_as_applied_open_from_above_across_the_vessel_at_the_site() {
    let down = Vector3::new(0.0, 0.0, -CLIP_DEPTH_M);
    let up = |mm: f64| Vector3::new(0.0, 0.0, mm * 1e-3);
    for seed in 0..3 {
        let new = || env(TaskId::VesselClipping, seed);
        let (site, along, cross) = clip_site(&new());
        let across = Vector3::new(-along.y, along.x, 0.0);
        // Honest: open jaws from above, across the vessel (square, and 15 deg oblique).
        for yaw_off in [0.0, 15f64.to_radians()] {
            let mut e = new();
            steer(&mut e, site + up(20.0), cross + yaw_off, OPEN, 0.01);
            steer(&mut e, site + down, cross + yaw_off, OPEN, 0.002);
            ended_succeeding(&hold(&mut e, CLOSED, 1), "an honest clip");
        }
        // Closed jaws pushed into the vessel's top (to open and close inside it): ends there.
        let mut e = new();
        steer(&mut e, site + up(20.0), cross, CLOSED, 0.01);
        let step = steer(&mut e, site + up(-1.0), cross, CLOSED, 0.002);
        ended_failing(
            &step,
            "a clip closes around it",
            "closed jaws into the vessel",
        );
        // Open jaws slid sideways through the vessel's wall, at the clip's height.
        let mut e = new();
        steer(&mut e, site + across * 0.008 + up(20.0), cross, OPEN, 0.01);
        steer(&mut e, site + across * 0.008 + down, cross, OPEN, 0.002);
        let step = steer(&mut e, site + down, cross, OPEN, 0.002);
        ended_failing(
            &step,
            "through the vessel's wall",
            "open jaws through the wall",
        );
        // Open jaws down into the vessel 12 mm along from the site, slid along inside to it and
        // closed: not a clip at the site.
        let mut e = new();
        steer(&mut e, site + along * 0.012 + up(20.0), cross, OPEN, 0.01);
        steer(&mut e, site + along * 0.012 + down, cross, OPEN, 0.002);
        steer(&mut e, site + down, cross, OPEN, 0.002);
        ended_failing(
            &hold(&mut e, CLOSED, 1),
            "slid along inside it",
            "slid along inside",
        );
        // Open jaws along the vessel come down onto it (to be closed, then twisted across): a
        // blade lands on the vessel, and the trial ends there.
        let mut e = new();
        steer(&mut e, site + up(20.0), cross + 1.5, OPEN, 0.01);
        let step = steer(&mut e, site + down, cross + 1.5, OPEN, 0.002);
        ended_failing(&step, "a blade lands on it", "open jaws along the vessel");
        // Across it as they came down, twisted along it inside and closed: judged as they
        // closed.
        let mut e = new();
        steer(&mut e, site + up(20.0), cross, OPEN, 0.01);
        steer(&mut e, site + down, cross, OPEN, 0.002);
        steer(&mut e, site + down, cross + 1.0, OPEN, 0.002);
        let step = hold(&mut e, CLOSED, 1);
        ended_failing(&step, "off crossing the vessel", "closed along the vessel");
    }
}

#[test]
fn a_stab_ends_a_touch_trial_when_it_happens() {
    for seed in 0..3 {
        let new = || env(TaskId::Electrocoagulation, seed);
        let e = new();
        let instance = e.instance();
        let spot = instance.scene.marks[instance.target_mark.expect("spot")].position_m;
        let yaw = e.sim_observation().state7()[5];
        let above = spot + Vector3::new(0.0, 0.0, 0.02);
        // Honest: closed jaws lowered onto the spot.
        let mut e = new();
        steer(&mut e, above, yaw, CLOSED, 0.01);
        ended_succeeding(&steer(&mut e, spot, yaw, CLOSED, 0.002), "a touch");
        // Through the surface 5 mm aside and tunnelling 3 mm under it to the spot: the trial
        // ends under the surface, before the tip comes out on the spot.
        let mut e = new();
        let aside = Vector3::new(0.005, 0.0, 0.0);
        steer(&mut e, above + aside, yaw, CLOSED, 0.01);
        let step = steer(
            &mut e,
            spot + aside - Vector3::new(0.0, 0.0, 0.004),
            yaw,
            CLOSED,
            0.002,
        );
        ended_failing(&step, "into the tissue", "a tunnel");
    }
}

/// T3-1 and T3-2: the gauze, the block (T3-1), and the gauze's rest height over the tray.
fn gauze_and_block(env: &Env) -> (usize, Option<usize>) {
    let instance = env.instance();
    (
        instance.target_object.expect("gauze"),
        instance.support_object,
    )
}

fn pose_of(env: &Env, index: usize) -> nalgebra::Isometry3<f64> {
    env.sim_observation().objects[index].world_from_object
}

/// Picks the gauze (jaws across its short side, 0.8 mm into its top) and lifts it 20 mm.
fn pick_gauze(env: &mut Env) {
    let (gauze, _) = gauze_and_block(env);
    let pose = pose_of(env, gauze);
    let yaw = wrap(pose.rotation.euler_angles().2);
    let top = pose.translation.vector + Vector3::new(0.0, 0.0, 0.0005);
    transit(env, top + Vector3::new(0.0, 0.0, 0.02), yaw, OPEN);
    steer(env, top, yaw, OPEN, 0.002);
    let step = hold(env, CLOSED, 1);
    assert_eq!(
        step.observation.sim.bound_object,
        Some(gauze),
        "{}",
        step.verdict.reason
    );
    steer(env, top + Vector3::new(0.0, 0.0, 0.02), yaw, CLOSED, 0.01);
}

/// Carries the held gauze over `target_m` and lowers it until its grasp point is `height_m`
/// above `target_m`, then opens and waits for it to settle; returns the last step.
fn set_down(env: &mut Env, target_m: Vector3<f64>, height_m: f64) -> EnvStep {
    let yaw = env.sim_observation().state7()[5];
    let over = target_m + Vector3::new(0.0, 0.0, 0.02);
    transit(env, over, yaw, CLOSED);
    let step = steer(
        env,
        target_m + Vector3::new(0.0, 0.0, height_m),
        yaw,
        CLOSED,
        0.002,
    );
    if step.done {
        return step;
    }
    let step = hold(env, OPEN, 1);
    if step.done {
        return step;
    }
    steer(env, over, yaw, OPEN, 0.002);
    hold(env, OPEN, 15)
}

/// The height of the gauze's grasp point (its centre) above the block's top when its underside
/// is `gap_m` above it.
fn over_block(gap_m: f64) -> f64 {
    surgvla::scene::GAUZE_HALF_EXTENTS_M[2] + surgvla::scene::BLOCK_HALF_EXTENTS_M[2] + gap_m
}

#[test]
fn a_drop_is_not_forgiven_by_a_regrasp_and_the_block_is_not_to_be_held() {
    for seed in 0..3 {
        let new = || env(TaskId::PickAndPlace, seed);
        let e = new();
        let (gauze, block) = gauze_and_block(&e);
        let block = block.expect("block");
        let on_block = pose_of(&e, block).translation.vector;
        // Honest: set down on the tray beside the block, picked up again, placed on the block.
        let mut e = new();
        pick_gauze(&mut e);
        let beside = pose_of(&e, gauze).translation.vector;
        let tray = surgvla::scene::TRAY_TOP_Z_M + surgvla::scene::GAUZE_HALF_EXTENTS_M[2];
        let step = set_down(&mut e, Vector3::new(beside.x, beside.y, tray), 0.001);
        assert!(
            !step.done,
            "seed {seed}: {} gauze {:?} block {:?} set down at {beside:?}",
            step.verdict.reason,
            pose_of(&e, gauze).translation.vector,
            pose_of(&e, block).translation.vector
        );
        pick_gauze(&mut e);
        ended_succeeding(
            &set_down(&mut e, on_block, over_block(0.002)),
            "a placement after a set-down",
        );
        // Dropped from 30 mm onto the block: the trial ends at the drop (a re-grasp comes
        // too late).
        let mut e = new();
        pick_gauze(&mut e);
        let step = set_down(&mut e, on_block, over_block(0.03));
        ended_failing(&step, "gauze dropped from", "a drop");
        // Placed properly, then the block gripped by its edge beside the gauze.
        let mut e = new();
        pick_gauze(&mut e);
        let mut step = set_down(&mut e, on_block, over_block(0.002));
        // The honest placement ends the trial with success; grip on in a longer one.
        assert!(step.verdict.success, "{}", step.verdict.reason);
        let block_pose = pose_of(&e, block);
        let edge = block_pose
            * nalgebra::Point3::new(
                0.0095,
                0.0,
                surgvla::scene::BLOCK_HALF_EXTENTS_M[2] + 0.0002,
            );
        let yaw = wrap(block_pose.rotation.euler_angles().2);
        steer(
            &mut e,
            edge.coords + Vector3::new(0.0, 0.0, 0.02),
            yaw,
            OPEN,
            0.01,
        );
        steer(&mut e, edge.coords, yaw, OPEN, 0.002);
        step = hold(&mut e, CLOSED, 1);
        assert!(
            !step.verdict.success,
            "seed {seed}: {}",
            step.verdict.reason
        );
        assert!(
            step.verdict.reason.contains("the gauze's support"),
            "{}",
            step.verdict.reason
        );
    }
}

#[test]
fn a_hemostasis_gauze_let_go_3_mm_aside_may_slide_and_still_cover_the_spot() {
    for seed in 0..4 {
        let mut e = env(TaskId::Hemostasis, seed);
        let instance = e.instance();
        let spot = instance.scene.marks[instance.target_mark.expect("spot")].position_m;
        pick_gauze(&mut e);
        let step = set_down(&mut e, spot + Vector3::new(0.003, 0.0, 0.0), 0.005);
        ended_succeeding(&step, "3 mm towards +x");
    }
}

/// A rendering T2-3 environment of `seed` and its first observation.
fn rendered_clipping(seed: u64) -> (Env, surgvla::env::EnvObservation) {
    let options = EnvOptions {
        max_steps: Some(600),
        ..EnvOptions::default()
    };
    let instance = TaskId::VesselClipping
        .instance(seed, &TaskConfig::default())
        .expect("spawn");
    Env::from_instance(instance, &options)
}

/// Brings open jaws across the vessel from 20 mm above the named site down to where the expert
/// closes them; returns the last step and the crossing yaw.
fn open_jaws_at_the_site(env: &mut Env) -> (EnvStep, f64) {
    let (site, _, cross) = clip_site(env);
    steer(env, site + Vector3::new(0.0, 0.0, 0.02), cross, OPEN, 0.01);
    let down = site - Vector3::new(0.0, 0.0, CLIP_DEPTH_M);
    (steer(env, down, cross, OPEN, 0.002), cross)
}

/// Every closing of the jaws on the vessel leaves a clip there, drawn across the vessel and
/// visible once the jaws are gone (its own mask class); before it, none is drawn.
#[test]
fn a_clip_is_left_on_the_vessel_where_the_jaws_closed() {
    let clip_id = surgvla::assets::MaskClass::Clip.id();
    let (mut e, first) = rendered_clipping(1);
    let clip_pixels = |mask: &[u8]| mask.iter().filter(|&&id| id == clip_id).count();
    assert_eq!(clip_pixels(&first.images.expect("rendered").mask), 0);
    let (_, cross) = open_jaws_at_the_site(&mut e);
    let (site, _, _) = clip_site(&e);
    ended_succeeding(&hold(&mut e, CLOSED, 1), "the clip");
    let away = steer(
        &mut e,
        site + Vector3::new(0.0, 0.0, 0.03),
        cross,
        OPEN,
        0.01,
    );
    let pixels = clip_pixels(&away.observation.images.expect("rendered").mask);
    assert!(pixels >= 4, "{pixels} clip pixels");
}

/// At 224 px the open jaws straddling T2-3's vessel are seen across it: the vessel runs towards
/// the endoscope, so jaws closing across it open left and right in the picture, wider than the
/// vessel and at least 6 px (they were 2-3 px with the vessel across the view).
#[test]
fn open_jaws_across_the_vessel_are_several_pixels_wide_in_the_picture() {
    use surgvla::assets::MaskClass;
    let (jaws, vessel) = (MaskClass::InstrumentJaws.id(), MaskClass::Vessel.id());
    for seed in 0..3 {
        let (mut e, _) = rendered_clipping(seed);
        let (step, _) = open_jaws_at_the_site(&mut e);
        let images = step.observation.images.expect("rendered");
        let width = 224;
        let columns = |id: u8, rows: std::ops::Range<usize>| {
            let cols: Vec<usize> = rows
                .flat_map(|r| (0..width).map(move |c| (r, c)))
                .filter(|&(r, c)| images.mask[r * width + c] == id)
                .map(|(_, c)| c)
                .collect();
            (cols.iter().min().copied(), cols.iter().max().copied())
        };
        let jaw_rows: Vec<usize> = (0..224)
            .filter(|r| images.mask[r * width..(r + 1) * width].contains(&jaws))
            .collect();
        let (first, last) = (jaw_rows[0], jaw_rows[jaw_rows.len() - 1]);
        let (Some(left), Some(right)) = columns(jaws, first..last + 1) else {
            panic!("seed {seed}: no jaws in the picture");
        };
        let (Some(v_left), Some(v_right)) = columns(vessel, last + 1..(last + 4).min(224)) else {
            panic!("seed {seed}: no vessel under the jaws");
        };
        let (span, vessel_width) = (right - left + 1, v_right - v_left + 1);
        assert!(span >= 6, "seed {seed}: the jaws span {span} px");
        assert!(
            span > vessel_width,
            "seed {seed}: jaws {span} px, vessel {vessel_width} px"
        );
    }
}
