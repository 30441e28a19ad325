"""surgvla from Python: gymnasium environments over surgvla's simulator (the eight laparoscopic
tasks of SurgVLA-Bench, scored by `surgvla eval`'s rules), a vector env stepped in Rust, the
scripted expert as a policy, and LeRobot's environment contract (`surgvla.lerobot`).

    import gymnasium, surgvla
    env = gymnasium.make("surgvla/GauzePick-v0")          # or surgvla.make("T1-1")
    obs, info = env.reset(seed=0)                          # trial 0 of `surgvla eval`
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

    envs = surgvla.make_vec("T1-1", num_envs=8)            # a gymnasium.vector.VectorEnv
    env = surgvla.make("T1-1", perturb="smoke=2")          # a variant of `eval --suite`

docs/python.md has every option.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from surgvla._native import __version__, suites, tasks
from surgvla.envs import GYM_IDS, RULE_SET, SurgvlaEnv, SurgvlaVectorEnv, register_envs, task_id

__all__ = [
    "GYM_IDS",
    "RULE_SET",
    "Expert",
    "SurgvlaEnv",
    "SurgvlaVectorEnv",
    "__version__",
    "expert",
    "make",
    "make_vec",
    "register_envs",
    "suites",
    "task_id",
    "tasks",
]

register_envs()


def make(task: str, **kwargs: Any):
    """`gymnasium.make` of a task by id ("T1-1"), name ("gauze_pick") or gymnasium id."""
    import gymnasium

    return gymnasium.make(GYM_IDS[task_id(task)], **kwargs)


def make_vec(task: str, num_envs: int = 8, **kwargs: Any) -> SurgvlaVectorEnv:
    """A vector env of `num_envs` environments of `task`, stepped together in Rust."""
    return SurgvlaVectorEnv(task_id(task), num_envs, **kwargs)


class Expert:
    """The task's scripted expert as a policy for an environment made here (privileged: it
    reads the simulator's state, as `surgvla eval --policy expert` does). `expert(observation)`
    returns the next action (one row per environment for a vector env) in the environment's
    action space; `done` says which experts have finished their plans (their rows then hold
    still). With `action_space="native"` the expert's own commands pass through unchanged, so
    its trials are `surgvla eval --policy expert`'s, step for step.
    """

    def __init__(self, env):
        base = getattr(env, "unwrapped", env)
        self._core = base._core
        self._single = isinstance(base, SurgvlaEnv)
        self._core.attach_expert()
        self.done = np.zeros(self._core.num_envs, dtype=bool)

    def __call__(self, observation: Any = None) -> np.ndarray:
        actions, self.done = self._core.expert_actions()
        return actions[0] if self._single else actions


def expert(env) -> Expert:
    """The scripted expert of `env`'s task (see `Expert`)."""
    return Expert(env)
