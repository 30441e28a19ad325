"""The README's first command, `cargo run --release -- collect` with its defaults, read by the
real lerobot 0.6.1 loader: 8 tasks x 100 verified episodes, about 40k frames.

The dataset is in the folder named by SURGVLA_LEROBOT_FULL_DATASET (see .ci/run).

The loader converts the parquet files to an Arrow cache (`datasets` writes it under
HF_DATASETS_CACHE), about 5x the dataset's size for the whole benchmark (9 GB) because depth is
raw float32 TIFF, as lerobot stores it, and Arrow keeps it uncompressed. So every frame goes
through the loader one task (100 episodes) at a time, each load with its own cache folder that is
deleted before the next: the disk holds at most one task's Arrow copy (about 1.2 GB).
"""

import json
import os
import random
import shutil
import tempfile
from pathlib import Path

import datasets
import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata  # noqa: E402

ROOT = Path(os.environ.get("SURGVLA_LEROBOT_FULL_DATASET", "")).resolve()
CODES = ["T1-1", "T1-2", "T1-3", "T2-1", "T2-2", "T2-3", "T3-1", "T3-2"]
EPISODES_PER_TASK = 100
FRAMES_SAMPLED_PER_TASK = 8
CLIP_SITES = {f"clip the {c} point on the vein" for c in ("yellow", "blue", "green")}
# The default collection uses the canonical instructions (docs/tasks.md).
CANONICAL = {
    "T1-1": {"pick up the gauze"},
    "T1-2": {"pick up the needle"},
    "T1-3": {"touch the red blood spot on the kidney"},
    "T2-1": {"pick up the gauze"},
    "T2-2": {"pick up the needle"},
    "T2-3": {"clip the red blood point on the vein"} | CLIP_SITES,
    "T3-1": {"pick up the gauze and place it on the block"},
    "T3-2": {"pick up the gauze and place it on the red target point on the spleen"},
}


@pytest.fixture(scope="module")
def meta():
    return LeRobotDatasetMetadata("surgvla/full", root=ROOT)


@pytest.fixture(scope="module")
def lengths(meta):
    return [meta.episodes[e]["length"] for e in range(meta.total_episodes)]


@pytest.fixture(scope="module")
def report():
    return json.loads((ROOT / "collect_report.json").read_text())


def load_task(task_number):
    """Loads one task's 100 episodes with the real loader, reads what the tests check, and
    deletes the Arrow cache the loader wrote."""
    first = task_number * EPISODES_PER_TASK
    episodes = list(range(first, first + EPISODES_PER_TASK))
    # `Dataset.from_parquet` reads the cache root from `datasets.config` when it is called.
    default_cache = datasets.config.HF_DATASETS_CACHE
    Path(default_cache).mkdir(parents=True, exist_ok=True)
    cache = tempfile.mkdtemp(prefix="surgvla-arrow-", dir=default_cache)
    datasets.config.HF_DATASETS_CACHE = cache
    try:
        dataset = LeRobotDataset("surgvla/full", root=ROOT, episodes=episodes, depth_output_unit="m")
        column = dataset.hf_dataset.data.column("episode_index").to_numpy()
        rng = random.Random(task_number)
        return {
            "episodes": sorted(set(column.tolist())),
            "frames": len(dataset),
            "task_indices": set(dataset.hf_dataset.data.column("task_index").to_numpy().tolist()),
            "items": [dataset[i] for i in rng.sample(range(len(dataset)), FRAMES_SAMPLED_PER_TASK)],
        }
    finally:
        datasets.config.HF_DATASETS_CACHE = default_cache
        shutil.rmtree(cache, ignore_errors=True)


@pytest.fixture(scope="module")
def tasks():
    return [load_task(t) for t in range(len(CODES))]


def test_the_default_collection_is_the_benchmark(meta, report):
    assert meta.total_episodes == 800 == report["episodes"]
    assert meta.total_frames == report["frames"]
    assert 30_000 <= meta.total_frames <= 50_000
    assert [t["code"] for t in report["tasks"]] == CODES
    for task in report["tasks"]:
        assert task["episodes"] == EPISODES_PER_TASK
        assert task["expert_success_rate"] >= 0.95, task
    # Canonical instructions; T2-3 names one of its three clip sites.
    instructions = set(meta.tasks.index)
    assert "pick up the gauze" in instructions and "pick up the needle" in instructions
    assert any(i.startswith("clip the") for i in instructions)


def test_every_episode_loads_task_by_task(meta, lengths, tasks):
    instruction_of = {index: text for text, index in meta.tasks["task_index"].items()}
    for number, seen in enumerate(tasks):
        first = number * EPISODES_PER_TASK
        assert seen["episodes"] == list(range(first, first + EPISODES_PER_TASK)), CODES[number]
        assert seen["frames"] == sum(lengths[first:first + EPISODES_PER_TASK]), CODES[number]
        names = {instruction_of[i] for i in seen["task_indices"]}
        assert names <= CANONICAL[CODES[number]], (CODES[number], names)


def test_random_frames_load_with_sane_values(tasks):
    for number, seen in enumerate(tasks):
        for item in seen["items"]:
            assert item["episode_index"] // EPISODES_PER_TASK == number
            assert item["observation.images.endoscope"].shape == (3, 224, 224)
            depth = item["observation.images.depth"]
            assert depth.shape == (1, 224, 224) and 0.05 < float(depth.max()) <= 0.3
            state = item["observation.state"].numpy()
            assert 0.49 < state[0] < 0.61 and -0.06 < state[1] < 0.06 and 0.67 < state[2] < 0.78
            action = item["action"].numpy()
            assert np.all(np.abs(action[:3]) <= 0.0101), action
            assert action[6] in (0.0, 1.0)


def test_episode_lengths_respect_the_step_limits(lengths):
    for number, code in enumerate(CODES):
        block = lengths[number * EPISODES_PER_TASK:(number + 1) * EPISODES_PER_TASK]
        limit = 150 if code.startswith("T3") else 100
        assert all(0 < n <= limit for n in block), (code, max(block))
