//! The optional dense reward of the Python environments: potential-based shaping (Ng, Harada
//! and Russell, 1999) over the task's stages, so a reinforcement learner gets a gradient before
//! its first success without changing which policies are optimal.
//!
//! The potential [`potential`] in [0, 1] of a state climbs the task's chain of stages:
//!
//! - tasks with an object to pick (T1-1, T1-2, T2-1, T2-2, T3-1, T3-2's gauze): half of it is
//!   the approach, `0.5 * (1 - min(1, d / 5 cm))` with `d` the tip's distance to the named
//!   object's grasp frame; the other half is holding that object (a held object counts the
//!   approach as done). T3-1 (place on the block) and T3-2 (place on the bleeding site) split
//!   the second half: a quarter for holding it, a quarter for bringing it over the target
//!   (`0.25 * (1 - min(1, d_xy / 5 cm))`, horizontal distance of the object to the target);
//! - tasks with a mark to touch or clip (T1-3, T2-3): `1 - min(1, d / 5 cm)` with `d` the tip's
//!   distance to the named mark.
//!
//! The dense reward of a step is `success + potential(after) - potential(before)`: the sparse
//! reward plus the shaping term. Holding the wrong object earns nothing.

use super::progress::{place_target_m, target_mark_m};
use crate::sim::Observation;
use crate::task::TaskInstance;
use nalgebra::Vector3;

/// The distance over which an approach term goes from 0 to its full share.
const APPROACH_SCALE_M: f64 = 0.05;

/// How far along the task's stages a state is, in [0, 1].
pub fn potential(instance: &TaskInstance, observation: &Observation) -> f64 {
    let tip = Vector3::from(observation.tip_position_m);
    let closeness = |d: f64| 1.0 - (d / APPROACH_SCALE_M).min(1.0);
    let mark = target_mark_m(instance);
    let Some(target) = instance.target_object else {
        return mark.map_or(0.0, |m| closeness((tip - m).norm()));
    };
    let Some(object) = observation.objects.get(target) else {
        return 0.0;
    };
    let position = object.world_from_object.translation.vector;
    if observation.bound_object != Some(target) {
        return 0.5 * closeness((tip - position).norm());
    }
    let place = place_target_m(instance.support_object, mark, observation);
    match place {
        Some(place) => 0.75 + 0.25 * closeness((position - place).xy().norm()),
        None => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::{Env, EnvOptions};
    use crate::policy::{ExpertLibrary, Policy};
    use crate::task::TaskId;

    /// The expert's run climbs the potential to its top on every task; an idle tool keeps it
    /// where it started.
    #[test]
    fn the_expert_climbs_the_potential_and_idling_does_not() {
        let library = ExpertLibrary::builtin().expect("plans");
        for task in TaskId::ALL {
            let (mut env, first) = Env::reset(task, 5, &EnvOptions::headless()).expect("spawn");
            let instance = env.instance().clone();
            let start = potential(&instance, &first.sim);
            assert!((0.0..1.0).contains(&start), "{task}: {start}");
            let plan = library.plan(task).expect("plan");
            let mut expert = plan.expert(&instance, &first.sim, 5).expect("expert");
            let mut peak = start;
            let mut observation = first.sim;
            while env.steps() < env.max_steps() && !expert.is_done() {
                let step = env.step_native(&expert.act(&observation));
                observation = step.observation.sim;
                peak = peak.max(potential(&instance, &observation));
                if step.verdict.success {
                    break;
                }
            }
            assert!(peak > 0.95, "{task}: the expert reached only {peak}");
            let (mut idle, first) = Env::reset(task, 5, &EnvOptions::headless()).expect("spawn");
            let hold = crate::sim::PhysicalAction::from_array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
            for _ in 0..5 {
                idle.step(&hold);
            }
            let after = potential(&instance, &idle.sim_observation());
            assert!(
                (after - potential(&instance, &first.sim)).abs() < 0.02,
                "{task}"
            );
        }
    }
}
