"""lerobot 0.6.1's own evaluation loop (`lerobot.scripts.lerobot_eval.eval_policy`) scores a
LeRobot policy on all eight tasks: an ACT policy that lerobot-train trained for one step on a
surgvla dataset, loaded with its processors, on the environments lerobot's own factory
(`lerobot.envs.factory.make_env`) builds from `examples/envhub/env.py` as an EnvHub repository
(served from a Hugging Face cache made here, offline).

SURGVLA_LEROBOT_TRAIN_DATASET: a `collect --without depth,environment_state` dataset.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ENV_PY = Path(__file__).resolve().parents[3] / "examples" / "envhub" / "env.py"

ROOT = Path(os.environ.get("SURGVLA_LEROBOT_TRAIN_DATASET", "")).resolve()
LEROBOT_TRAIN = Path(sys.executable).resolve().parent / "lerobot-train"


@pytest.fixture(scope="module")
def act_checkpoint(tmp_path_factory) -> Path:
    assert (ROOT / "meta" / "info.json").is_file(), ROOT
    out = tmp_path_factory.mktemp("act") / "out"
    train = os.environ.get("SURGVLA_LEROBOT_TRAIN_BIN", str(LEROBOT_TRAIN))
    run = subprocess.run(
        [
            train,
            "--dataset.repo_id=surgvla/benchmark",
            f"--dataset.root={ROOT}",
            "--policy.type=act",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            "--policy.pretrained_backbone_weights=null",
            "--wandb.enable=false",
            f"--output_dir={out}",
            "--steps=1",
            "--save_freq=1",
            "--batch_size=2",
            "--num_workers=0",
        ],
        capture_output=True,
        text=True,
        env=dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1"),
        timeout=1800,
    )
    assert run.returncode == 0, (run.stdout + run.stderr)[-4000:]
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    assert (checkpoint / "config.json").is_file(), list(out.rglob("*"))
    return checkpoint


def hub_cache(root: Path) -> Path:
    """A Hugging Face cache holding the model repository `surgvla/envhub` with `env.py`, as
    `hf_hub_download` leaves one (refs/main -> snapshots/<commit>/)."""
    commit = "0" * 40
    repo = root / "models--surgvla--envhub"
    (repo / "refs").mkdir(parents=True)
    (repo / "refs" / "main").write_text(commit)
    snapshot = repo / "snapshots" / commit
    snapshot.mkdir(parents=True)
    (snapshot / "env.py").write_text(ENV_PY.read_text())
    return root


def test_eval_policy_scores_act_on_all_eight_tasks(act_checkpoint, tmp_path):
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.scripts.lerobot_eval import eval_policy

    from lerobot.envs.factory import make_env

    import surgvla

    policy = ACTPolicy.from_pretrained(act_checkpoint)
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(act_checkpoint))
    identity = PolicyProcessorPipeline(steps=[])
    assert os.environ.get("HF_HUB_OFFLINE") == "1", "run offline: the cache below is the Hub"
    envs = make_env("surgvla/envhub", n_envs=2, trust_remote_code=True, hub_cache_dir=str(hub_cache(tmp_path / "hub")))
    assert list(envs) == ["surgvla"] and list(envs["surgvla"]) == list(surgvla.GYM_IDS)
    for task, env in envs["surgvla"].items():
        info = eval_policy(
            env,
            policy,
            identity,
            identity,
            preprocessor,
            postprocessor,
            n_episodes=2,
            start_seed=0,
        )
        aggregated = info["aggregated"]
        assert "pc_success" in aggregated and 0.0 <= aggregated["pc_success"] <= 100.0, task
        assert len(info["per_episode"]) == 2 and [e["seed"] for e in info["per_episode"]] == [0, 1], task
        env.close()
