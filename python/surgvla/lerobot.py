"""LeRobot's environment contract: `make_env(n_envs, use_async_envs)` in the EnvHub shape, so
lerobot's own evaluation loop (`lerobot.scripts.lerobot_eval.eval_policy`) scores a LeRobot
policy on surgvla's tasks in-process. An EnvHub repository's `env.py` is one line
(`examples/envhub/env.py`):

    from surgvla.lerobot import make_env  # noqa: F401

Observations use the keys LeRobot maps to dataset features: `pixels` as `{"endoscope": image}`
becomes `observation.images.endoscope` (the camera of surgvla's LeRobot datasets), `agent_pos`
becomes `observation.state`, `environment_state` becomes `observation.environment_state`.
"""

from __future__ import annotations

from typing import Any

from surgvla.envs import GYM_IDS, SurgvlaVectorEnv, task_id

SUITE = "surgvla"
CAMERA = "endoscope"

#: Environment key -> the LeRobot feature a policy trained on a surgvla dataset reads.
FEATURES_MAP = {
    "action": "action",
    "agent_pos": "observation.state",
    "environment_state": "observation.environment_state",
    f"pixels/{CAMERA}": f"observation.images.{CAMERA}",
}


def make_env(
    n_envs: int = 1,
    use_async_envs: bool = False,
    tasks: list[str] | None = None,
    **kwargs: Any,
) -> dict[str, dict[str, SurgvlaVectorEnv]]:
    """`{"surgvla": {task_id: vector env}}` with `n_envs` environments per task (all eight tasks
    unless `tasks` names some). `use_async_envs` is accepted and changes nothing: the vector env
    already steps its environments in parallel threads. Other options go to
    `SurgvlaVectorEnv` (e.g. `environment_state=True`, `eval_seed=0`)."""
    del use_async_envs
    kwargs.setdefault("camera_name", CAMERA)
    chosen = [task_id(t) for t in tasks] if tasks else list(GYM_IDS)
    return {SUITE: {code: SurgvlaVectorEnv(code, n_envs, **kwargs) for code in chosen}}
