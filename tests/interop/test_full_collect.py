"""The README's first command, `cargo run --release -- collect` with its defaults, read by the
real lerobot 0.6.1 loader: 8 tasks x 100 verified episodes, about 40k frames.

The dataset is in the folder named by SURGVLA_LEROBOT_FULL_DATASET (see .ci/run).
"""

import json
import os
import random
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

ROOT = Path(os.environ.get("SURGVLA_LEROBOT_FULL_DATASET", "")).resolve()


@pytest.fixture(scope="module")
def dataset():
    return LeRobotDataset("surgvla/full", root=ROOT, depth_output_unit="m")


@pytest.fixture(scope="module")
def report():
    return json.loads((ROOT / "collect_report.json").read_text())


def test_the_default_collection_is_the_benchmark(dataset, report):
    assert dataset.num_episodes == 800 == report["episodes"]
    assert dataset.num_frames == report["frames"]
    assert 30_000 <= dataset.num_frames <= 50_000
    codes = [t["code"] for t in report["tasks"]]
    assert codes == ["T1-1", "T1-2", "T1-3", "T2-1", "T2-2", "T2-3", "T3-1", "T3-2"]
    for task in report["tasks"]:
        assert task["episodes"] == 100
        assert task["expert_success_rate"] >= 0.95, task
    # Canonical instructions; T2-3 names one of its three clip sites.
    instructions = set(dataset.meta.tasks.index)
    assert "pick up the gauze" in instructions and "pick up the needle" in instructions
    assert any(i.startswith("clip the") for i in instructions)


def test_random_frames_load_with_sane_values(dataset):
    rng = random.Random(0)
    for i in rng.sample(range(len(dataset)), 64):
        item = dataset[i]
        assert item["observation.images.endoscope"].shape == (3, 224, 224)
        depth = item["observation.images.depth"]
        assert depth.shape == (1, 224, 224) and 0.05 < float(depth.max()) <= 0.3
        state = item["observation.state"].numpy()
        assert 0.49 < state[0] < 0.61 and -0.06 < state[1] < 0.06 and 0.67 < state[2] < 0.78
        action = item["action"].numpy()
        assert np.all(np.abs(action[:3]) <= 0.0101), action
        assert action[6] in (0.0, 1.0)


def test_episode_lengths_respect_the_step_limits(dataset):
    episodes = dataset.meta.episodes
    lengths = [episodes[e]["length"] for e in range(dataset.num_episodes)]
    for task_index in range(8):
        block = lengths[task_index * 100:(task_index + 1) * 100]
        limit = 150 if task_index >= 6 else 100
        assert all(0 < n <= limit for n in block), (task_index, max(block))
