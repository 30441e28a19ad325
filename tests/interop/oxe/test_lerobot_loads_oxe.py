"""lerobot 0.6.1 loads surgvla's LeRobot conversions of the Open X-Embodiment specs that
tests/interop/rlds/test_oxe_specs.py builds with tensorflow_datasets (it leaves them in
SURGVLA_OXE_OUT, one folder per spec; .ci/run runs this file in the lerobot venv after the
RLDS step): every frame loads, with the task as the instruction the spec stored and one
`action` of the width surgvla's mapping gives.
"""

import json
import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

# As in test_oxe_specs.py: the action's width per spec, the instructions of its episodes.
ACTION_WIDTH = {
    "fractal20220817_data": 7, "bridge": 7, "taco_play": 7, "jaco_play": 4, "language_table": 2,
    "austin_buds_dataset_converted_externally_to_rlds": 7,
    "maniskill_dataset_converted_externally_to_rlds": 7,
}
INSTRUCTIONS = {"pick up the gauze", "place the can upright"}


@pytest.fixture(scope="module")
def out():
    root = os.environ.get("SURGVLA_OXE_OUT")
    if not root or not Path(root).is_dir():
        pytest.fail("SURGVLA_OXE_OUT names no folder: run tests/interop/rlds/test_oxe_specs.py with it first")
    return Path(root)


@pytest.mark.parametrize("name", sorted(ACTION_WIDTH))
def test_lerobot_loads_each_oxe_conversion(out, name):
    root = out / name
    dataset = LeRobotDataset(f"oxe/{name}", root=root)
    assert len(dataset) == 7 and dataset.num_episodes == 2
    info = json.loads((root / "meta/info.json").read_text())
    assert info["features"]["action"]["shape"] == [ACTION_WIDTH[name]]
    for index in range(len(dataset)):
        item = dataset[index]
        assert tuple(item["action"].shape) == (ACTION_WIDTH[name],)
        assert item["task"] in INSTRUCTIONS, item["task"]
