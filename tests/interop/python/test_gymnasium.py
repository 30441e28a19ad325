"""The surgvla wheel's Python module under its real clients: gymnasium 1.x's own environment
checker and vector API, Stable-Baselines3's PPO, and the scripted expert scored through the
vector env against `surgvla eval --policy expert` (same trials, same successes, same steps).

Run with an interpreter where the wheel is installed (beside gymnasium, torch and
stable-baselines3); SURGVLA_BIN: the surgvla binary.
"""

import json
import os
import subprocess
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import surgvla

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
TASK_IDS = list(surgvla.GYM_IDS)


@pytest.mark.parametrize("gym_id", list(surgvla.GYM_IDS.values()))
def test_check_env_passes_for_every_task(gym_id):
    env = gymnasium.make(gym_id)
    check_env(env.unwrapped, skip_render_check=False)
    state = gymnasium.make(gym_id, obs_type="state")
    check_env(state.unwrapped)
    depth = gymnasium.make(gym_id, depth=True, mask=True, environment_state=True, render_mode="rgb_array")
    check_env(depth.unwrapped)


def test_observations_info_and_render():
    env = surgvla.make("T2-1", depth=True, mask=True, environment_state=True, render_mode="rgb_array")
    obs, info = env.reset(seed=3)
    assert obs["pixels"].shape == (224, 224, 3) and obs["pixels"].dtype == np.uint8
    assert obs["depth"].dtype == np.float32 and obs["depth"].max() > 0.05
    assert obs["mask"].shape == (224, 224) and len(np.unique(obs["mask"])) > 2
    assert obs["agent_pos"].shape == (7,) and obs["environment_state"].shape == (28,)
    assert info["trial"] == 3 and info["task_description"] == "pick up the gauze"
    # The success rules datasets record (collect_report.json's success_rules).
    assert info["rule_set"] == surgvla.RULE_SET and surgvla.RULE_SET.startswith("surgvla-physical-v")
    frame = env.render()
    assert np.array_equal(frame, obs["pixels"])
    # The instruction variants of `--instructions`.
    paraphrased = surgvla.make("T1-1", instructions="paraphrase")
    said = {paraphrased.reset(seed=s)[1]["task_description"] for s in range(12)}
    assert said <= set(surgvla.envs.TASKS["T1-1"]["paraphrases"]) and len(said) > 1
    # obs_type="state" renders nothing.
    state = surgvla.make("T1-1", obs_type="state")
    obs, _ = state.reset(seed=0)
    assert set(obs) == {"agent_pos", "environment_state"} and state.render() is None


def test_an_idle_policy_is_truncated_at_the_step_limit_and_fails():
    env = surgvla.make("T1-3")
    env.reset(seed=0)
    hold = np.array([0, 0, 0, 0, 0, 0, 1], dtype=np.float32)
    for step in range(1, 151):
        obs, reward, terminated, truncated, info = env.step(hold)
        if terminated or truncated:
            break
    assert (step, terminated, truncated, reward) == (100, False, True, 0.0)
    assert not info["is_success"] and "step limit" in info["reason"]


def test_a_vector_env_of_8_runs_gymnasiums_api():
    envs = surgvla.make_vec("T1-1", num_envs=8, max_episode_steps=4)
    assert isinstance(envs, gymnasium.vector.VectorEnv)
    assert envs.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.NEXT_STEP
    obs, info = envs.reset(seed=10)
    assert obs["pixels"].shape == (8, 224, 224, 3) and obs["agent_pos"].shape == (8, 7)
    assert list(info["trial"]) == list(range(10, 18))
    assert envs.observation_space.contains(obs)
    for step in range(4):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert truncated.all() and not terminated.any() and reward.shape == (8,)
    # Next-step autoreset: the step after the end starts trials 18..25 and ignores the actions.
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert info["autoreset"].all() and list(info["trial"]) == list(range(18, 26))
    assert not (terminated | truncated).any() and (reward == 0).all()
    # The same seed gives the same observations.
    again, _ = envs.reset(seed=10)
    first, _ = surgvla.make_vec("T1-1", num_envs=8).reset(seed=10)
    assert np.array_equal(again["pixels"], first["pixels"])
    # gymnasium.make_vec through the registered vector entry point.
    made = gymnasium.make_vec("surgvla/GauzePick-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert made.num_envs == 2 and made.reset(seed=0)[0]["pixels"].shape[0] == 2
    # And through gymnasium's own SyncVectorEnv over the single environment.
    sync = gymnasium.make_vec("surgvla/GauzePick-v0", num_envs=2, vectorization_mode="sync")
    sync_obs, _ = sync.reset(seed=10)
    assert np.array_equal(sync_obs["pixels"], first["pixels"][:2])


def test_the_dense_reward_is_shaping_and_the_expert_earns_it():
    env = surgvla.make_vec("T1-1", num_envs=2, obs_type="state", reward="dense", action_space="native")
    env.reset(seed=0)
    expert = surgvla.expert(env)
    total = np.zeros(2)
    done = np.zeros(2, dtype=bool)
    while not done.all():
        _, reward, terminated, truncated, info = env.step(expert())
        total += np.where(done, 0, reward)
        done |= terminated | truncated
    # 1 for the success plus the potential climbed from its start to 1.
    assert (total > 1.5).all() and (total <= 2.0 + 1e-9).all(), total


def test_ppo_learns_on_the_state_observation():
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = surgvla.make("T1-1", obs_type="state", reward="dense", action_space="native")
    sb3_check(env.unwrapped)
    model = PPO("MultiInputPolicy", env, n_steps=128, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(action.astype(np.float32))


def vector_expert(task: str, trials: int, **options) -> list[tuple[int, bool, int]]:
    """(trial, success, steps) of the expert through the vector env, as `eval` runs a trial:
    until success, the step limit, or the expert has nothing left to do."""
    options = {"obs_type": "state", **options}
    envs = surgvla.make_vec(task, num_envs=trials, action_space="native", **options)
    envs.reset(seed=0)
    expert = surgvla.expert(envs)
    results: dict[int, tuple[int, bool, int]] = {}
    steps = np.zeros(trials, dtype=int)
    while len(results) < trials:
        actions = expert()
        for i in np.flatnonzero(expert.done):
            results.setdefault(i, (i, False, int(steps[i])))
        _, _, terminated, truncated, info = envs.step(actions)
        steps += 1
        for i in np.flatnonzero(terminated | truncated):
            results.setdefault(i, (i, bool(info["is_success"][i]), int(info["steps"][i])))
    return [results[i] for i in range(trials)]


def test_the_experts_trials_equal_surgvla_eval(tmp_path: Path):
    trials = 6
    out = tmp_path / "eval"
    subprocess.run(
        [BIN, "eval", "--policy", "expert", "--trials", str(trials), "--record-failures", "0", "--out", str(out)],
        check=True,
        capture_output=True,
    )
    scored = json.loads((out / "results.json").read_text())["trials"]
    for task in TASK_IDS:
        expected = [(t["trial"], t["success"], t["steps"]) for t in scored if t["task_id"] == task]
        assert vector_expert(task, trials) == expected, task


def test_the_environments_take_evals_perturbation_variants(tmp_path: Path):
    suites = surgvla.suites()
    assert suites["all-v1"][0] == "none" and "smoke=2" in suites["all-v1"]
    plain = surgvla.make("T3-2")
    smoky = surgvla.make("T3-2", perturb="smoke=2")
    moved = surgvla.make("T3-2", perturb="camera_pose=2")
    (o, _), (s, _), (m, _) = (e.reset(seed=3) for e in (plain, smoky, moved))
    # The images change, the robot does not; smoke flattens the image's contrast.
    assert np.array_equal(o["agent_pos"], s["agent_pos"]) and np.array_equal(o["agent_pos"], m["agent_pos"])
    assert s["pixels"].std() < 0.8 * o["pixels"].std()
    assert (m["pixels"] != o["pixels"]).mean() > 0.3
    told = surgvla.make("T2-1", perturb="detailed=1", obs_type="state")
    _, info = told.reset(seed=0)
    assert info["task_description"] == "pick up the gauze, not the needle"
    with pytest.raises(ValueError, match="unknown perturbation dimension `fog`"):
        surgvla.make("T1-1", perturb="fog=1")
    # The expert's trials under a visual variant are eval's under it, step for step.
    out = tmp_path / "eval"
    subprocess.run(
        [BIN, "eval", "--policy", "expert", "--tasks", "T1-1", "--trials", "3", "--perturb", "blur=2"]
        + ["--record-failures", "0", "--out", str(out)],
        check=True,
        capture_output=True,
    )
    scored = json.loads((out / "results.json").read_text())["trials"]
    assert {t["variant"] for t in scored} == {"blur=2"}
    expected = [(t["trial"], t["success"], t["steps"]) for t in scored]
    assert vector_expert("T1-1", 3, obs_type="pixels", perturb="blur=2") == expected
