"""Datasets lerobot 0.6.1 itself wrote (tests/interop/lerobot leaves them in
SURGVLA_LEROBOT_MADE: float64 vectors; an AV1 camera beside an HEVC depth video) converted by
surgvla to RLDS, read by tensorflow_datasets: actions and states equal what lerobot stored
(float64 as the float32 TFRecord holds), the HEVC depth left out by `--without` with a note.
The same datasets go to zarr and MCAP with `--camera`, into SURGVLA_ROLES_OUT/specs/<name> with
the actions they must hold, for zarr 3 (tests/interop/clouds) and the mcap reader
(tests/interop/mcap), which read them back.
"""

import json
import os
import subprocess
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
import pytest  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
MADE = Path(os.environ.get("SURGVLA_LEROBOT_MADE", ""))
# Per dataset: its camera, and what must be left out (HEVC, which surgvla does not decode).
DATASETS = {
    "float64": ("observation.images.top", []),
    "hevc_depth": ("observation.images.top", ["--without", "observation.images.depth"]),
}


def run(*args):
    done = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    return done.returncode, done.stderr


@pytest.mark.parametrize("name", sorted(DATASETS))
def test_a_dataset_lerobot_wrote_converts_to_rlds_zarr_and_mcap(name, tmp_path):
    source = MADE / name
    if not (source / "meta/info.json").is_file():
        pytest.fail(f"SURGVLA_LEROBOT_MADE holds no {name}: run tests/interop/lerobot with it first")
    camera, without = DATASETS[name]
    stored = pq.read_table(source / "data/chunk-000/file-000.parquet")
    dtype = np.float64 if str(stored.schema.field("action").type.value_type) == "double" else np.float32
    table = stored.to_pydict()
    actions = np.array(table["action"], dtype)
    states = np.array(table["observation.state"], dtype)
    out = tmp_path / "rlds"
    code, err = run("convert", source, "--to", "rlds", *without, "--out", out, "--verify")
    assert code == 0, err
    if without:
        assert f"left out {without[1]}" in err, err
    code, err = run("validate", out)
    assert code == 0, err
    config = tfds.ReadConfig(interleave_cycle_length=1)
    dataset = tfds.builder_from_directory(str(next(out.glob("*/*")))).as_dataset(split="train", shuffle_files=False, read_config=config)
    steps = [s for e in dataset for s in e["steps"].as_numpy_iterator()]
    assert len(steps) == len(actions)
    np.testing.assert_array_equal(np.stack([s["action"] for s in steps]), actions.astype(np.float32))
    np.testing.assert_array_equal(np.stack([s["observation"]["state"] for s in steps]), states.astype(np.float32))
    # zarr and MCAP, for their readers.
    folder = Path(os.environ.get("SURGVLA_ROLES_OUT") or tmp_path / "roles") / "specs" / f"lerobot_{name}"
    import shutil

    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    for to in ["zarr", "mcap"]:
        code, err = run("convert", source, "--to", to, "--camera", camera, *without, "--out", folder / to)
        assert code == 0, err
        code, err = run("validate", folder / to)
        assert code == 0, err
    lengths = list(np.bincount(np.array(table["episode_index"])))
    np.savez(folder / "expected.npz", action=actions)
    (folder / "expected.json").write_text(json.dumps({"action": actions.tolist(), "lengths": [int(n) for n in lengths]}))
