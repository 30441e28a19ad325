"""lerobot-train, the real lerobot 0.6.1 training script, on surgvla datasets.

docs/training.md's recipe (`collect --without depth,environment_state`, then `lerobot-train` with ACT
or Diffusion) must run: two optimisation steps on CPU with randomly initialised backbones and no
network. The default dataset, whose depth (and here mask) images have one channel, must fail the
way that made `--without` necessary, so this test also documents why the option exists.

SURGVLA_LEROBOT_TRAIN_DATASET: a `collect --without depth,environment_state` dataset.
SURGVLA_LEROBOT_DATASET: a dataset with depth and mask (1-channel image features).
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

TRAIN_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_TRAIN_DATASET", "")).resolve()
DEFAULT_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_DATASET", "")).resolve()
# The console script installed with lerobot, beside this interpreter.
LEROBOT_TRAIN = Path(sys.executable).parent / "lerobot-train"


def train(root: Path, policy: str, output_dir: Path) -> subprocess.CompletedProcess:
    """The README's command, shortened to two steps on CPU with no downloads."""
    command = [
        str(LEROBOT_TRAIN),
        "--dataset.repo_id=surgvla/benchmark",
        f"--dataset.root={root}",
        f"--policy.type={policy}",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.pretrained_backbone_weights=null",
        "--wandb.enable=false",
        f"--output_dir={output_dir}",
        "--steps=2",
        "--batch_size=2",
        "--num_workers=0",
        "--log_freq=1",
        "--save_checkpoint=false",
    ]
    environment = dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1")
    return subprocess.run(
        command, capture_output=True, text=True, env=environment, timeout=1800
    )


@pytest.mark.parametrize("policy", ["act", "diffusion"])
def test_the_readme_recipe_trains(policy, tmp_path):
    assert (TRAIN_ROOT / "meta" / "info.json").is_file(), TRAIN_ROOT
    run = train(TRAIN_ROOT, policy, tmp_path / "out")
    output = run.stdout + run.stderr
    assert run.returncode == 0, output[-4000:]
    # Two optimisation steps were logged (lerobot logs "step:1" and "step:2" with log_freq 1).
    assert "step:2" in output, output[-4000:]


@pytest.mark.parametrize(
    ("policy", "said"),
    [
        ("diffusion", "but we expect all image shapes to match"),
        ("act", "channels"),
    ],
)
def test_the_default_datasets_one_channel_images_stop_training(policy, said, tmp_path):
    assert (DEFAULT_ROOT / "meta" / "info.json").is_file(), DEFAULT_ROOT
    run = train(DEFAULT_ROOT, policy, tmp_path / "out")
    output = run.stdout + run.stderr
    assert run.returncode != 0, output[-4000:]
    assert said in output, output[-4000:]
