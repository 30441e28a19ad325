"""A LeRobot dataset lerobot 0.6.1 writes with float64 vectors (an arm logging doubles):
`surgvla convert` keeps them float64, every double bit for bit, and lerobot loads the result;
`--cast float32` narrows them, saying so on stderr and in the card, with every value the
float32 nearest the stored double; the card says which dataset the data came from and invents
no licence.

SURGVLA_BIN is the surgvla binary.
"""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")


def make(root: Path) -> Path:
    features = {
        "observation.state": {"dtype": "float64", "shape": (3,), "names": ["x", "y", "z"]},
        "action": {"dtype": "float64", "shape": (3,), "names": ["dx", "dy", "dz"]},
        "observation.images.top": {"dtype": "image", "shape": (16, 20, 3), "names": ["height", "width", "channels"]},
    }
    dataset = LeRobotDataset.create("someone/doubles", fps=10, features=features, root=root, robot_type="arm", use_videos=False)
    rng = np.random.default_rng(2)
    for episode in range(2):
        for _ in range(4 + episode):
            dataset.add_frame({
                "observation.state": rng.standard_normal(3) * 1e3 + 1 / 3,
                "action": rng.standard_normal(3) / 7,
                "observation.images.top": rng.integers(0, 255, (16, 20, 3), dtype=np.uint8),
                "task": "reach",
            })
        dataset.save_episode()
    dataset.finalize()
    return root


def surgvla(*args):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)


def test_float64_stays_float64_unless_cast(tmp_path):
    source = make(tmp_path / "doubles")
    # For the other clients' readers (tests/interop/rlds/test_lerobot_made.py, run later by .ci/run).
    if os.environ.get("SURGVLA_LEROBOT_MADE"):
        import shutil

        shutil.copytree(source, Path(os.environ["SURGVLA_LEROBOT_MADE"]) / "float64", dirs_exist_ok=True)
    original = pq.read_table(source / "data/chunk-000/file-000.parquet").to_pydict()
    kept = tmp_path / "kept"
    done = surgvla("convert", source, "--to", "lerobot", "--out", kept, "--verify")
    assert done.returncode == 0, done.stderr
    assert surgvla("validate", kept).returncode == 0
    info = json.loads((kept / "meta/info.json").read_text())
    assert info["features"]["observation.state"]["dtype"] == "float64", info["features"]
    table = pq.read_table(kept / "data/chunk-000/file-000.parquet")
    assert str(table.schema.field("observation.state").type.value_type) == "double", table.schema
    converted = table.to_pydict()
    for key in ["observation.state", "action"]:
        assert np.array_equal(np.array(converted[key], np.float64), np.array(original[key], np.float64)), key
    loaded = LeRobotDataset("someone/doubles", root=kept)
    assert len(loaded) == 9 and loaded[0]["observation.state"].dtype.is_floating_point
    out = tmp_path / "cast"
    done = surgvla("convert", source, "--to", "lerobot", "--cast", "float32", "--out", out, "--verify")
    assert done.returncode == 0, done.stderr
    assert "observation.state is float64: read as float32 (--cast float32)" in done.stderr, done.stderr
    assert surgvla("validate", out).returncode == 0
    card = (out / "README.md").read_text()
    assert "the input is the LeRobot dataset doubles (v3.0)" in card and "license: apache-2.0" not in card, card
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["observation.state"]["dtype"] == "float32"
    converted = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    for key in ["observation.state", "action"]:
        expected = np.array(original[key], np.float64).astype(np.float32)
        assert np.array_equal(np.array(converted[key], np.float32), expected), key
    loaded = LeRobotDataset("someone/doubles", root=out)
    assert len(loaded) == 9
    # The other targets: zarr keeps doubles (<f8), MCAP's JSON writes them exactly, RLDS
    # declares float64 and stores float32 as TFRecord does (a note says so).
    for to, extra in [("zarr", ["--camera", "observation.images.top"]), ("mcap", ["--camera", "observation.images.top"]), ("rlds", [])]:
        target = tmp_path / to
        done = surgvla("convert", source, "--to", to, *extra, "--out", target)
        assert done.returncode == 0, done.stderr
        assert surgvla("validate", target).returncode == 0, to
    zarray = json.loads((tmp_path / "zarr/data/state/.zarray").read_text())
    assert zarray["dtype"] == "<f8" and zarray["shape"] == [9, 3], zarray
    assert "an RLDS output stores float32" in done.stderr, done.stderr
