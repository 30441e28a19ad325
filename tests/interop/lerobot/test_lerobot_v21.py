"""surgvla's LeRobot v2.1 layout, read the way lerobot 0.6.1 reads v2.1: through its own
converter (`lerobot.scripts.convert_dataset_v21_to_v30`, local, no hub), then `LeRobotDataset`.

SURGVLA_LEROBOT_V21_DATASET holds `surgvla collect --lerobot-version 2.1` output (copied before
conversion, which rewrites the folder); SURGVLA_LEROBOT_DATASET the same episodes as v3.0.
"""

import os
import shutil
from pathlib import Path

import pytest
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402
from lerobot.scripts.convert_dataset_v21_to_v30 import convert_dataset  # noqa: E402

V21_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_V21_DATASET", "")).resolve()
V30_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_DATASET", "")).resolve()


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    root = tmp_path_factory.mktemp("v21") / "dataset"
    shutil.copytree(V21_ROOT, root)
    convert_dataset("surgvla/interop-v21", root=root, push_to_hub=False)
    return LeRobotDataset("surgvla/interop-v21", root=root, depth_output_unit="m")


def test_v21_layout_is_what_the_converter_expects():
    info = (V21_ROOT / "meta" / "info.json").read_text()
    assert '"codebase_version": "v2.1"' in info
    assert (V21_ROOT / "meta" / "episodes.jsonl").exists()
    assert (V21_ROOT / "data" / "chunk-000" / "episode_000000.parquet").exists()


def test_converted_v21_equals_the_v30_dataset(converted):
    reference = LeRobotDataset("surgvla/interop", root=V30_ROOT, depth_output_unit="m")
    assert converted.num_episodes == reference.num_episodes
    assert len(converted) == len(reference)
    for i in range(len(reference)):
        a, b = converted[i], reference[i]
        assert a["task"] == b["task"]
        for key in ["observation.images.endoscope", "observation.images.depth", "observation.state", "action", "timestamp", "index", "episode_index"]:
            assert torch.equal(a[key], b[key]), (i, key)
