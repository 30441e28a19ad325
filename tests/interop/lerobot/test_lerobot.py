"""surgvla's LeRobot datasets, loaded by the real lerobot 0.6.1 loader.

The dataset under test is written by `surgvla collect` (see .ci/run) into the folder named by
SURGVLA_LEROBOT_DATASET. Expected values are read independently of surgvla's own reader:
straight from the parquet files with pyarrow, images decoded with Pillow.
"""

import io
import json
import os
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from PIL import Image

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

ROOT = Path(os.environ.get("SURGVLA_LEROBOT_DATASET", "")).resolve()
RGB = "observation.images.endoscope"
DEPTH = "observation.images.depth"
MASK = "observation.images.mask"


@pytest.fixture(scope="module")
def info():
    return json.loads((ROOT / "meta" / "info.json").read_text())


@pytest.fixture(scope="module")
def dataset():
    # Depth stored in metres (depth_unit "m"); ask for metres back to compare bit for bit.
    return LeRobotDataset("surgvla/interop", root=ROOT, depth_output_unit="m")


@pytest.fixture(scope="module")
def rows():
    """Every frame as written, read straight from the parquet files."""
    tables = [pq.read_table(p) for p in sorted((ROOT / "data").glob("*/*.parquet"))]
    out = []
    for table in tables:
        out.extend(table.to_pylist())
    return out


def test_metadata_counts_and_features(dataset, info, rows):
    assert info["codebase_version"] == "v3.0"
    assert dataset.num_frames == info["total_frames"] == len(rows)
    assert dataset.num_episodes == info["total_episodes"]
    assert dataset.fps == info["fps"] == 5
    assert dataset.meta.robot_type == "dvrk_psm"
    for key in [RGB, DEPTH, "observation.state", "action", "observation.environment_state"]:
        assert key in dataset.features
    assert dataset.features[DEPTH]["info"]["is_depth_map"] is True
    assert len(dataset.features["observation.state"]["names"]) == 7


def test_every_frame_matches_what_was_written(dataset, rows, info):
    fps = info["fps"]
    tasks = dataset.meta.tasks
    for i in range(len(dataset)):
        item = dataset[i]
        row = rows[i]
        assert item["index"].item() == i == row["index"]
        assert item["episode_index"].item() == row["episode_index"]
        assert item["frame_index"].item() == row["frame_index"]
        assert abs(item["timestamp"].item() - row["frame_index"] / fps) < 1e-6
        assert isinstance(item["task"], str) and item["task"] == tasks.iloc[row["task_index"]].name
        assert "gauze" in item["task"] or "needle" in item["task"]

        rgb = item[RGB]
        assert rgb.shape == (3, 224, 224) and rgb.dtype == torch.float32
        expected = np.asarray(Image.open(io.BytesIO(row[RGB]["bytes"])).convert("RGB"))
        assert np.array_equal((rgb.numpy() * 255).round().astype(np.uint8).transpose(1, 2, 0), expected), i

        depth = item[DEPTH]
        assert depth.shape == (1, 224, 224) and depth.dtype == torch.float32
        expected_depth = np.asarray(Image.open(io.BytesIO(row[DEPTH]["bytes"])), dtype=np.float32)
        assert np.array_equal(depth.numpy()[0], expected_depth), i
        assert 0.0 <= float(depth.max()) <= 0.3 and float(depth.max()) > 0.05

        if MASK in item:
            mask = item[MASK]
            assert mask.shape == (1, 224, 224)

        for key, length in [("observation.state", 7), ("action", 7), ("observation.environment_state", 28)]:
            value = item[key]
            assert value.shape == (length,) and value.dtype == torch.float32
            assert np.array_equal(value.numpy(), np.asarray(row[key], dtype=np.float32)), (i, key)
        gripper = item["action"][6].item()
        assert gripper in (0.0, 1.0), "continuous gripper state: 1 open, 0 closed on every step"


def test_depth_converts_to_millimetres_by_default(dataset):
    in_mm = LeRobotDataset("surgvla/interop", root=ROOT)
    for i in [0, len(dataset) // 2, len(dataset) - 1]:
        metres = dataset[i][DEPTH].numpy()
        millimetres = in_mm[i][DEPTH].numpy()
        assert np.allclose(millimetres, metres * 1000.0, rtol=1e-6, atol=1e-6)


def test_action_chunks_pad_at_episode_ends(info):
    fps = info["fps"]
    horizon = 8
    chunked = LeRobotDataset(
        "surgvla/interop",
        root=ROOT,
        delta_timestamps={"action": [k / fps for k in range(horizon)]},
        depth_output_unit="m",
    )
    episodes = chunked.meta.episodes
    for episode in range(chunked.num_episodes):
        start = episodes[episode]["dataset_from_index"]
        end = episodes[episode]["dataset_to_index"]
        last = chunked[end - 1]
        assert last["action"].shape == (horizon, 7)
        pad = last["action_is_pad"]
        assert pad.tolist() == [False] + [True] * (horizon - 1)
        first = chunked[start]
        assert first["action_is_pad"].sum().item() == max(0, horizon - (end - start))
        # The chunk starting at frame 0 is the episode's first `horizon` actions.
        plain = [chunked.hf_dataset[start + k]["action"] for k in range(min(horizon, end - start))]
        for k, expected in enumerate(plain):
            assert np.allclose(first["action"][k].numpy(), np.asarray(expected, dtype=np.float32))


def test_stats_have_quantiles_and_image_shapes(dataset):
    stats = dataset.meta.stats
    for key in ["observation.state", "action"]:
        for stat in ["min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"]:
            assert stat in stats[key], (key, stat)
        assert np.asarray(stats[key]["mean"]).shape == (7,)
    rgb_mean = np.asarray(stats[RGB]["mean"])
    assert rgb_mean.shape == (3, 1, 1) and 0.0 < rgb_mean.min() and rgb_mean.max() < 1.0


def test_collect_report_and_instructions_match_the_dataset(dataset):
    """`surgvla collect` ran with --instructions mixed: several phrasings reach LeRobot's task
    table, and collect_report.json agrees with what the loader sees."""
    report = json.loads((ROOT / "collect_report.json").read_text())
    assert report["episodes"] == dataset.num_episodes
    assert report["frames"] == dataset.num_frames
    assert sum(t["episodes"] for t in report["tasks"]) == dataset.num_episodes
    for task in report["tasks"]:
        assert 0.0 < task["expert_success_rate"] <= 1.0
        assert task["attempts"] >= task["episodes"]
    assert len(dataset.meta.tasks) >= 3
    surgvla = json.loads((ROOT / "meta" / "surgvla.json").read_text())
    assert surgvla["collection"]["instructions"] == "mixed"
    assert surgvla["collection"]["gripper_encoding"] == "continuous"
    # Every episode closes the jaws at some point and starts with them open.
    episodes = dataset.meta.episodes
    for episode in range(dataset.num_episodes):
        start = episodes[episode]["dataset_from_index"]
        end = episodes[episode]["dataset_to_index"]
        gripper = [dataset.hf_dataset[k]["action"][6] for k in range(start, end)]
        assert gripper[0] == 1.0 and 0.0 in gripper


def test_episode_provenance_loads_through_the_loader(dataset):
    """Each episode's provenance (surgvla/seed, task_id, level, attempts, success) is in the
    episodes table the real loader reads, and agrees with the report and the metadata."""
    report = json.loads((ROOT / "collect_report.json").read_text())
    episodes = dataset.meta.episodes
    names = set(episodes.column_names)
    for key in ["surgvla/seed", "surgvla/task_id", "surgvla/level", "surgvla/attempts", "surgvla/success"]:
        assert key in names, f"{key} missing from {sorted(names)}"
    collected = [t["code"] for t in report["tasks"]]
    seeds = set()
    for episode in range(dataset.num_episodes):
        row = episodes[episode]
        assert row["surgvla/task_id"] in collected
        assert row["surgvla/level"] == int(row["surgvla/task_id"][1])
        assert row["surgvla/attempts"] >= 1
        assert row["surgvla/success"] is True
        seeds.add(row["surgvla/seed"])
    assert len(seeds) == dataset.num_episodes, "every saved attempt has its own seed"
    per_task = {t["code"]: t["attempts"] for t in report["tasks"]}
    for code, attempts in per_task.items():
        rows = [episodes[e] for e in range(dataset.num_episodes) if episodes[e]["surgvla/task_id"] == code]
        assert sum(r["surgvla/attempts"] for r in rows) == attempts


def card_snippet(root):
    """The Python code block of the dataset card's "Loading" section."""
    card = (root / "README.md").read_text()
    return card.split("## Loading", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]


def test_the_cards_loading_snippet_runs_as_written(monkeypatch, info):
    monkeypatch.chdir(ROOT)
    scope = {}
    exec(card_snippet(ROOT), scope)
    assert len(scope["dataset"]) == info["total_frames"]
    assert tuple(scope["frame"]["action"].shape) == (7,)
    assert tuple(scope["frame"][RGB].shape) == (3, 224, 224)
