"""Environment steps per second from Python (BENCHMARKS.md, "Python environments"): the vector
env (`surgvla.make_vec`, stepped in Rust with the GIL released) beside one plain gymnasium step
loop over the single environment (`gymnasium.make`), side by side in one run, with
224 x 224 RGB observations and with `obs_type="state"` (no rendering).

    python scripts/bench_python.py [--task T1-1] [--num-envs 8] [--seconds 10]

Actions are uniform samples of the action space (seeded), so episodes run to the step limit and
autoreset: the rate includes the resets. Run it with an interpreter where the wheel is installed.
"""

import argparse
import os
import time

import gymnasium
import numpy as np

import surgvla


def rate(step, reset, seconds: float, per_step: int) -> float:
    reset()
    steps, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        step()
        steps += per_step
    return steps / (time.perf_counter() - started)


def vector(task: str, n: int, obs_type: str, seconds: float) -> float:
    envs = surgvla.make_vec(task, num_envs=n, obs_type=obs_type)
    envs.action_space.seed(0)
    return rate(lambda: envs.step(envs.action_space.sample()), lambda: envs.reset(seed=0), seconds, n)


def single(task: str, obs_type: str, seconds: float) -> float:
    env = gymnasium.make(surgvla.GYM_IDS[task], obs_type=obs_type)
    env.action_space.seed(0)

    def step():
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    return rate(step, lambda: env.reset(seed=0), seconds, 1)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="T1-1")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    print(f"surgvla {surgvla.__version__}, {os.cpu_count()} cores, task {args.task}")
    print("| observation | make_vec (num_envs=%d) | gymnasium.make, one env | ratio |" % args.num_envs)
    print("|---|---|---|---|")
    for obs_type, label in (("pixels", "224 x 224 RGB + state"), ("state", "state (no rendering)")):
        v = vector(args.task, args.num_envs, obs_type, args.seconds)
        s = single(args.task, obs_type, args.seconds)
        print(f"| {label} | {v:,.0f} steps/s | {s:,.0f} steps/s | {v / s:.1f}x |")


if __name__ == "__main__":
    main()
