//! The eight tasks with their experts: experts succeed, idle and random policies do not,
//! distractors are not picked, and replaying corrupted actions is caught.

use surgvla::collect::record::{attempt_seed, run_expert, verify_replay};
use surgvla::collect::rollout;
use surgvla::episode::GripperEncoding;
use surgvla::policy::{ExpertLibrary, Policy, RandomPolicy};
use surgvla::sim::{NativeCommand, Observation, SimConfig, Simulator};
use surgvla::task::{TaskConfig, TaskId, TaskInstance};

fn library() -> ExpertLibrary {
    ExpertLibrary::builtin().expect("built-in plans")
}

fn instance(task: TaskId, k: u64, config: &TaskConfig) -> TaskInstance {
    task.instance(attempt_seed(77, task, k, 0), config)
        .expect("a valid scene")
}

#[test]
fn every_expert_succeeds_and_its_actions_replay_to_success() {
    let library = library();
    let encodings = [GripperEncoding::Continuous, GripperEncoding::Pulse];
    for task in TaskId::ALL {
        for k in 0..6 {
            let instance = instance(task, k, &TaskConfig::default());
            let encoding = encodings[k as usize % 2];
            let plan = library.plan(task).unwrap();
            let run = run_expert(&instance, plan, task.step_limit(), encoding).unwrap();
            assert!(run.verdict.success, "{task} k {k}: {}", run.verdict.reason);
            assert!(run.actions.len() <= task.step_limit() as usize);
            let replay = verify_replay(&instance, &run.actions, encoding);
            assert!(replay.success, "{task} k {k} replay: {}", replay.reason);
            // Every recorded action lies in the reference's action space as recorded (eval's
            // clipping changes none), roll and pitch exact zeros.
            for action in &run.actions {
                let physical = surgvla::sim::PhysicalAction::from_array(action.map(f64::from));
                let (within, clipped) = physical.within_reference();
                assert!(!clipped, "{task} k {k}: {action:?}");
                assert_eq!(within.to_array(), physical.to_array(), "{task} k {k}");
                assert_eq!((action[3], action[4]), (0.0, 0.0), "{task} k {k}");
            }
            // The gripper column is the continuous state unless pulse was asked for.
            let gripper: Vec<f32> = run.actions.iter().map(|a| a[6]).collect();
            if encoding == GripperEncoding::Continuous {
                assert!(gripper.iter().all(|g| *g == 0.0 || *g == 1.0));
                assert!(gripper.iter().filter(|g| **g == 0.0).count() > 1, "{task}");
            } else {
                assert!(gripper.iter().filter(|g| **g != 0.0).count() <= 3, "{task}");
            }
        }
    }
}

#[test]
fn the_experts_vary_between_episodes() {
    let library = library();
    let actions = |k| {
        let instance = instance(TaskId::GauzePick, k, &TaskConfig::default());
        let plan = library.plan(TaskId::GauzePick).unwrap();
        run_expert(&instance, plan, 100, GripperEncoding::Continuous)
            .unwrap()
            .actions
    };
    let (a, b) = (actions(0), actions(1));
    assert_ne!(a, b);
    assert_ne!(a.len(), 0);
}

/// Runs `policy` for the task's step limit and asserts the predicate never holds.
fn never_succeeds(instance: &TaskInstance, policy: &mut dyn Policy, label: &str) {
    let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
    let trajectory = rollout(&mut sim, policy, instance.task.step_limit());
    let observations: Vec<&Observation> = trajectory
        .steps
        .iter()
        .map(|s| &s.observation)
        .chain(std::iter::once(&trajectory.final_observation))
        .collect();
    assert_eq!(observations.len(), instance.task.step_limit() as usize + 1);
    for observation in observations {
        let verdict = instance.success(observation);
        assert!(
            !verdict.success,
            "{} {label} step {}: {}",
            instance.task, observation.step_index, verdict.reason
        );
    }
}

struct Idle;

impl Policy for Idle {
    fn act(&mut self, _: &Observation) -> NativeCommand {
        NativeCommand::default()
    }

    fn is_done(&self) -> bool {
        false
    }
}

#[test]
fn idle_and_random_policies_never_satisfy_a_predicate() {
    for task in TaskId::ALL {
        for k in 0..3 {
            let instance = instance(task, k, &TaskConfig::default());
            never_succeeds(&instance, &mut Idle, "idle");
            never_succeeds(&instance, &mut RandomPolicy::new(k * 31 + 5), "random");
        }
    }
}

#[test]
fn distractor_tasks_pick_the_named_object_and_a_distractor_is_no_success() {
    let library = library();
    for task in [TaskId::GauzePickDistractors, TaskId::NeedlePickDistractors] {
        for distractors in 1..=3 {
            let config = TaskConfig {
                distractors,
                ..TaskConfig::default()
            };
            for k in 0..3 {
                let instance = instance(task, k, &config);
                let plan = library.plan(task).unwrap();
                let run = run_expert(&instance, plan, 100, GripperEncoding::Continuous).unwrap();
                assert!(
                    run.verdict.success,
                    "{task} {distractors} k {k}: {}",
                    run.verdict.reason
                );
                let name = &instance.scene.objects[instance.target_object.unwrap()].name;
                assert!(
                    run.verdict.reason.contains(name.as_str()),
                    "{}",
                    run.verdict.reason
                );

                // The same expert aimed at a distractor grasps it: a terminal failure, the
                // attempt ends the moment it binds.
                let distractor = instance
                    .scene
                    .objects
                    .iter()
                    .position(|o| o.distractor)
                    .unwrap();
                let decoy = TaskInstance {
                    target_object: Some(distractor),
                    ..instance.clone()
                };
                // Aimed with the expert of the distractor's own kind (a gauze expert does not
                // land on a needle's wire).
                let decoy_plan = match instance.scene.objects[distractor].kind {
                    surgvla::scene::ObjectKind::Needle => library.plan(TaskId::NeedlePick),
                    _ => library.plan(TaskId::GauzePick),
                }
                .unwrap();
                let wrong =
                    run_expert(&decoy, decoy_plan, 100, GripperEncoding::Continuous).unwrap();
                assert!(!wrong.verdict.success);
                assert!(
                    wrong.verdict.reason.contains("grasped the distractor"),
                    "{}",
                    wrong.verdict.reason
                );
                let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
                for action in &wrong.actions {
                    let mut values = action.map(f64::from);
                    values[6] = if action[6] >= 0.5 { 1.0 } else { 0.0 };
                    sim.step_physical(&surgvla::sim::PhysicalAction::from_array(values));
                }
                let observation = sim.observation();
                assert_eq!(observation.bound_object, Some(distractor), "{task} k {k}");
                let verdict = instance.success(&observation);
                assert!(!verdict.success);
                assert!(
                    verdict.reason.contains("grasped the distractor"),
                    "{}",
                    verdict.reason
                );
                // Putting it back and taking the target afterwards does not help: the binding
                // is remembered.
                sim.step_native(&surgvla::sim::NativeCommand {
                    jaw: 1.0,
                    ..Default::default()
                });
                let after = sim.observation();
                assert_eq!(after.bound_object, None);
                assert!(after.objects[distractor].ever_bound);
                assert!(instance.terminal_failure(&after).is_some());
            }
        }
    }
}

#[test]
fn the_vessel_expert_clips_the_site_the_instruction_names() {
    let library = library();
    for k in 0..6 {
        let instance = instance(TaskId::VesselClipping, k, &TaskConfig::default());
        let target = &instance.scene.marks[instance.target_mark.unwrap()];
        assert!(instance.instruction.contains(target.colour.name()));
        let plan = library.plan(TaskId::VesselClipping).unwrap();
        let run = run_expert(&instance, plan, 100, GripperEncoding::Continuous).unwrap();
        assert!(
            run.verdict.reason.contains(&target.name),
            "{}",
            run.verdict.reason
        );
        // Clipping another site fails the predicate.
        let other = (instance.target_mark.unwrap() + 1) % instance.scene.marks.len();
        let decoy = TaskInstance {
            target_mark: Some(other),
            ..instance.clone()
        };
        let wrong = run_expert(&decoy, plan, 100, GripperEncoding::Continuous).unwrap();
        assert!(wrong.verdict.success, "the decoy run clips its own site");
        let verdict = verify_replay(&instance, &wrong.actions, GripperEncoding::Continuous);
        assert!(
            !verdict.success && verdict.reason.contains(&target.name),
            "{}",
            verdict.reason
        );
    }
}

#[test]
fn replay_verification_catches_corrupted_actions() {
    let library = library();
    let encoding = GripperEncoding::Continuous;
    for task in [TaskId::GauzePick, TaskId::NeedlePick, TaskId::PickAndPlace] {
        let instance = instance(task, 2, &TaskConfig::default());
        let plan = library.plan(task).unwrap();
        let run = run_expert(&instance, plan, task.step_limit(), encoding).unwrap();
        assert!(verify_replay(&instance, &run.actions, encoding).success);
        let close = run.actions.iter().position(|a| a[6] == 0.0).unwrap();

        // The gripper never closes.
        let mut open = run.actions.clone();
        open.iter_mut().for_each(|a| a[6] = 1.0);
        assert!(!verify_replay(&instance, &open, encoding).success, "{task}");

        // One step 12 mm off just before the close: the jaws close on nothing.
        let mut shifted = run.actions.clone();
        shifted[close - 1][0] += 0.012;
        let verdict = verify_replay(&instance, &shifted, encoding);
        assert!(!verdict.success, "{task}: {}", verdict.reason);
    }
}
