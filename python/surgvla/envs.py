"""gymnasium environments over surgvla's simulator: `SurgvlaEnv` (one environment) and
`SurgvlaVectorEnv` (many, stepped together in Rust with the GIL released).

Both run `surgvla eval`'s scenes, step limits, action clipping and success predicates (the
simulator, renderer and tasks are the compiled module's; nothing is re-implemented here).

Seeds are trials: `reset(seed=k)` starts trial k of `surgvla eval --seed <eval_seed>` (the
same scene), so seeds 0..49 are the 50 trials `surgvla eval --trials 50` scores. An unseeded
reset (and a vector env's autoreset) continues with trial k + num_envs.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from surgvla import _native
from surgvla._native import VectorCore, tasks

#: gymnasium ids by task id, in benchmark order.
GYM_IDS = {
    "T1-1": "surgvla/GauzePick-v0",
    "T1-2": "surgvla/NeedlePick-v0",
    "T1-3": "surgvla/Electrocoagulation-v0",
    "T2-1": "surgvla/GauzePickDistractors-v0",
    "T2-2": "surgvla/NeedlePickDistractors-v0",
    "T2-3": "surgvla/VesselClipping-v0",
    "T3-1": "surgvla/PickAndPlace-v0",
    "T3-2": "surgvla/Hemostasis-v0",
}
TASKS = {t["id"]: t for t in tasks()}
CONTROL_HZ = 5
#: One step of the dataset action space: 1 cm per axis, no roll or pitch, 30 deg of yaw.
MAX_STEP_M = 0.01
MAX_STEP_YAW_RAD = float(np.pi / 6)
#: Bound of the state values (metres, radians, quaternion components): the workspace is a few
#: centimetres around (0.55, 0, 0.72) m, angles lie within +-pi.
BOUND = 10.0


def task_id(task: str) -> str:
    """The task id ("T1-1") of a task id, name ("gauze_pick") or gymnasium id."""
    for code, info in TASKS.items():
        if task in (code, info["name"], GYM_IDS[code], GYM_IDS[code].split("/")[1]):
            return code
    raise ValueError(f"no task {task!r}: one of {list(TASKS)} or {list(GYM_IDS.values())}")


def action_space(kind: str) -> spaces.Box:
    """The dataset's 7-D action space, or the native 5-D command in [-1, 1]."""
    if kind == "native":
        return spaces.Box(-1.0, 1.0, shape=(5,), dtype=np.float32)
    if kind != "dataset":
        raise ValueError(f"action_space {kind!r}: 'dataset' or 'native'")
    high = np.array([MAX_STEP_M] * 3 + [0.0, 0.0, MAX_STEP_YAW_RAD, 1.0], dtype=np.float32)
    low = np.array([-MAX_STEP_M] * 3 + [0.0, 0.0, -MAX_STEP_YAW_RAD, 0.0], dtype=np.float32)
    return spaces.Box(low, high, dtype=np.float32)


class _Options:
    """What both environment classes take, checked once."""

    def __init__(
        self,
        task: str,
        obs_type: str = "pixels",
        render_mode: str | None = None,
        depth: bool = False,
        mask: bool = False,
        environment_state: bool | None = None,
        camera_name: str | None = None,
        action_space: str = "dataset",
        reward: str = "sparse",
        instructions: str = "canonical",
        eval_seed: int = 0,
        distractors: int = 1,
        spawn_scale: float | None = None,
        max_episode_steps: int | None = None,
        threads: int = 0,
        perturb: str = "none",
    ):
        if obs_type not in ("pixels", "state"):
            raise ValueError(f"obs_type {obs_type!r}: 'pixels' or 'state'")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: None or 'rgb_array'")
        if obs_type == "state" and (depth or mask or camera_name):
            raise ValueError("depth, mask and camera_name need obs_type='pixels'")
        self.task = task_id(task)
        self.obs_type = obs_type
        self.render_mode = render_mode
        self.depth, self.mask, self.camera_name = depth, mask, camera_name
        # Privileged object poses: always with obs_type="state", opt-in with pixels.
        self.environment_state = obs_type == "state" if environment_state is None else environment_state
        self.action_space = action_space
        self.kwargs = dict(
            render=obs_type == "pixels" or render_mode == "rgb_array",
            depth=depth,
            mask=mask,
            actions=action_space,
            reward=reward,
            instructions=instructions,
            seed=eval_seed,
            distractors=distractors,
            spawn_scale=spawn_scale,
            max_steps=max_episode_steps,
            threads=threads,
            perturb=perturb,
        )

    def core(self, num_envs: int) -> VectorCore:
        return VectorCore(self.task, num_envs, **self.kwargs)

    def observation_space(self, core: VectorCore) -> spaces.Dict:
        h, w = core.image_size
        entries: dict[str, spaces.Space] = {}
        if self.obs_type == "pixels":
            image = spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)
            entries["pixels"] = spaces.Dict({self.camera_name: image}) if self.camera_name else image
            if self.depth:
                entries["depth"] = spaces.Box(0.0, BOUND, shape=(h, w), dtype=np.float32)
            if self.mask:
                entries["mask"] = spaces.Box(0, 255, shape=(h, w), dtype=np.uint8)
        entries["agent_pos"] = spaces.Box(-BOUND, BOUND, shape=(7,), dtype=np.float32)
        if self.environment_state:
            entries["environment_state"] = spaces.Box(-BOUND, BOUND, shape=(28,), dtype=np.float32)
        return spaces.Dict(entries)

    def observation(self, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
        """The batched observation dict from the core's arrays (no copies)."""
        out: dict[str, Any] = {}
        if self.obs_type == "pixels":
            pixels = arrays["pixels"]
            out["pixels"] = {self.camera_name: pixels} if self.camera_name else pixels
            for key in ("depth", "mask"):
                if key in arrays:
                    out[key] = arrays[key]
        out["agent_pos"] = arrays["agent_pos"]
        if self.environment_state:
            out["environment_state"] = arrays["environment_state"]
        return out


def _row(observation: dict[str, Any], i: int) -> dict[str, Any]:
    return {k: _row(v, i) if isinstance(v, dict) else v[i] for k, v in observation.items()}


def _trials(seed: int | list[int | None] | None, n: int) -> list[int | None]:
    if seed is None:
        return [None] * n
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + i for i in range(n)]
    seeds = list(seed)
    if len(seeds) != n:
        raise ValueError(f"{len(seeds)} seeds for {n} environments")
    return [None if s is None else int(s) for s in seeds]


class SurgvlaEnv(gym.Env):
    """One environment of a task (see the module's docstring and docs/python.md).

    Observations: `pixels` (224 x 224 x 3 uint8; a dict `{camera_name: image}` when
    `camera_name` is given), `agent_pos` (the 7-D state), and as asked `depth` (metres),
    `mask` (object ids) and `environment_state` (28 object pose values, privileged; always with
    `obs_type="state"`, which renders nothing). Info: `is_success`, `reason` (what the
    predicate found), `task_description` (the instruction), `trial`, `seed` (the scene's),
    `steps`, `clipped` (the action had to be changed), `rule_set`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_HZ}

    def __init__(self, task: str = "T1-1", **kwargs: Any):
        # One environment needs no worker pool of its own (many of them in gymnasium's
        # SyncVectorEnv would each start one per core).
        kwargs.setdefault("threads", 1)
        self._options = _Options(task, **kwargs)
        self.render_mode = self._options.render_mode
        self._core = self._options.core(1)
        self.observation_space = self._options.observation_space(self._core)
        self.action_space = action_space(self._options.action_space)
        self.task_id = self._options.task
        self._max_episode_steps = self._core.max_steps

    @property
    def task_description(self) -> str:
        """The instruction the current episode gives (what LeRobot's eval loop reads)."""
        return self._core.instructions()[0]

    @property
    def task(self) -> str:
        return self.task_description

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        arrays = self._core.reset(_trials(seed, 1))
        return _row(self._options.observation(arrays), 0), self._info(None, [""])

    def step(self, action):
        actions = np.asarray(action, dtype=np.float64)
        if actions.shape != self.action_space.shape:
            raise ValueError(f"an action of shape {actions.shape}; the action space's is {self.action_space.shape}")
        actions = actions.reshape(1, -1)
        arrays, outcome, reasons = self._core.step(actions)
        observation = _row(self._options.observation(arrays), 0)
        info = self._info(outcome, reasons)
        return (
            observation,
            float(outcome["reward"][0]),
            bool(outcome["terminated"][0]),
            bool(outcome["truncated"][0]),
            info,
        )

    def _info(self, outcome: dict[str, np.ndarray] | None, reasons: list[str]) -> dict[str, Any]:
        trial, seed = self._core.trials()[0]
        info = {
            "is_success": bool(outcome["is_success"][0]) if outcome else False,
            "reason": reasons[0],
            "task_description": self.task_description,
            "task_id": self.task_id,
            "trial": trial,
            # uint64: scene seeds use all 64 bits (gymnasium's vector envs keep the dtype).
            "seed": np.uint64(seed),
            "steps": int(outcome["steps"][0]) if outcome else 0,
            "clipped": bool(outcome["clipped"][0]) if outcome else False,
            "rule_set": RULE_SET,
        }
        return info

    def render(self):
        return self._core.frame(0)


class SurgvlaVectorEnv(VectorEnv):
    """`num_envs` environments of one task stepped together in Rust (the GIL released, a rayon
    pool of `threads` workers, 0: one per core): batched numpy observations, gymnasium 1.x's
    next-step autoreset. Same options as `SurgvlaEnv`."""

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": CONTROL_HZ,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(self, task: str = "T1-1", num_envs: int = 1, **kwargs: Any):
        self._options = _Options(task, **kwargs)
        self.render_mode = self._options.render_mode
        self._core = self._options.core(num_envs)
        self.num_envs = num_envs
        self.task_id = self._options.task
        self.single_observation_space = self._options.observation_space(self._core)
        self.single_action_space = action_space(self._options.action_space)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._max_episode_steps = self._core.max_steps

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
        arrays = self._core.reset(_trials(seed, self.num_envs))
        return self._options.observation(arrays), self._info(None, [""] * self.num_envs)

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != self.action_space.shape:
            raise ValueError(f"actions of shape {actions.shape}; the action space's is {self.action_space.shape}")
        arrays, outcome, reasons = self._core.step(actions)
        info = self._info(outcome, reasons)
        return (
            self._options.observation(arrays),
            outcome["reward"],
            outcome["terminated"],
            outcome["truncated"],
            info,
        )

    def _info(self, outcome: dict[str, np.ndarray] | None, reasons: list[str]) -> dict[str, Any]:
        n = self.num_envs
        trials = np.array(self._core.trials(), dtype=np.uint64).reshape(n, 2)
        info: dict[str, Any] = {
            "is_success": outcome["is_success"] if outcome else np.zeros(n, dtype=bool),
            "reason": np.array(reasons, dtype=object),
            "task_description": np.array(self._core.instructions(), dtype=object),
            "trial": trials[:, 0].astype(np.int64),
            "seed": trials[:, 1],
        }
        if outcome:
            for key in ("steps", "clipped", "autoreset"):
                info[key] = outcome[key]
        # gymnasium's vector info convention: `_key` marks which environments carry `key`.
        everyone = np.ones(n, dtype=bool)
        for key in list(info):
            info["_" + key] = everyone
        return info

    # What LeRobot's eval loop (and gymnasium's wrappers) ask a vector env for.
    def get_attr(self, name: str) -> tuple[Any, ...]:
        if name in ("task_description", "task"):
            return tuple(self._core.instructions())
        if name == "_max_episode_steps":
            return (self._max_episode_steps,) * self.num_envs
        if name == "task_id":
            return (self.task_id,) * self.num_envs
        if name == "render_mode":
            return (self.render_mode,) * self.num_envs
        raise AttributeError(f"SurgvlaVectorEnv has no per-environment attribute {name!r}")

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        if name == "render":
            return tuple(self._core.frame(i) for i in range(self.num_envs))
        return self.get_attr(name)

    def render(self) -> tuple[np.ndarray, ...] | None:
        frames = self.call("render")
        return None if frames[0] is None else frames

    @property
    def task_description(self) -> list[str]:
        return self._core.instructions()


#: The success rules these environments judge by: `surgvla eval`'s and `collect`'s
#: (docs/FIDELITY.md), as datasets record them in `success_rules`.
RULE_SET = _native.RULE_SET


def register_envs() -> None:
    """Registers the eight `surgvla/<Name>-v0` ids with gymnasium (done on `import surgvla`)."""
    for code, env_id in GYM_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="surgvla.envs:SurgvlaEnv",
            vector_entry_point="surgvla.envs:SurgvlaVectorEnv",
            max_episode_steps=TASKS[code]["max_steps"],
            kwargs={"task": code},
        )
