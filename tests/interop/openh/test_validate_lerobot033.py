"""`surgvla validate` (full and `--quick`) and `info` on LeRobot v2.1 datasets lerobot 0.3.3
writes itself (the version Open-H pins; image and video mode): valid, with the totals their
own info.json states. lerobot 0.3.3 writes per-episode statistics only (no meta/stats.json).

SURGVLA_BIN is the surgvla binary.
"""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")


def make(root: Path, video: bool) -> Path:
    """Three episodes of a dVRK-like arm: 8-D state and action, one camera."""
    camera = {"dtype": "video" if video else "image", "shape": (48, 64, 3), "names": ["height", "width", "channels"]}
    features = {
        "observation.state": {"dtype": "float32", "shape": (8,), "names": [f"s{i}" for i in range(8)]},
        "action": {"dtype": "float32", "shape": (8,), "names": [f"a{i}" for i in range(8)]},
        "observation.images.left": camera,
    }
    dataset = LeRobotDataset.create("someone/dvrk-like", fps=30, features=features, root=root, robot_type="dvrk", use_videos=video)
    rng = np.random.default_rng(0)
    for episode, task in enumerate(["cut the suture", "tie the knot", "cut the suture"]):
        for _ in range(10 + episode):
            dataset.add_frame({
                "observation.state": rng.standard_normal(8).astype(np.float32),
                "action": rng.standard_normal(8).astype(np.float32),
                "observation.images.left": rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
            }, task=task)
        dataset.save_episode()
    return root


def surgvla_json(*args: str) -> tuple[int, dict]:
    run = subprocess.run([BIN, *args, "--json"], capture_output=True, text=True)
    return run.returncode, json.loads(run.stdout)


@pytest.mark.parametrize("video", [False, True], ids=["images", "videos"])
def test_validate_quick_and_info_take_what_lerobot_0_3_3_writes(tmp_path, video):
    dataset = make(tmp_path / "dataset", video)
    info = json.loads((dataset / "meta/info.json").read_text())
    assert info["codebase_version"] == "v2.1"
    assert not (dataset / "meta/stats.json").exists(), "0.3.3 writes per-episode statistics only"
    totals = (info["total_episodes"], info["total_frames"])
    for args in (["validate"], ["validate", "--quick"], ["info"]):
        code, report = surgvla_json(*args, str(dataset))
        assert code == 0, (args, report.get("errors"))
        assert (report["episodes"], report["frames"]) == totals, args
