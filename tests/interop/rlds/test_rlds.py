"""surgvla's RLDS datasets, read by the real tensorflow_datasets (and OpenVLA's standardisation).

.ci/run writes, from the same options and seed:
- SURGVLA_LEROBOT_DATASET: a LeRobot dataset (`collect`, with the mask), the reference values;
- SURGVLA_RLDS_DATASET: `collect --format rlds --rlds-shard-mb 1` (several shards);
- SURGVLA_RLDS_CONVERTED: `convert <the LeRobot dataset> --to rlds`;
- SURGVLA_RLDS_JPEG: the same with `--rlds-image-encoding jpeg` (quality 95);
- SURGVLA_RLDS_PULSE: `collect --format rlds --gripper-encoding pulse`, whose OPENVLA.md
  rebuilds the absolute gripper.

Expected values are read independently of surgvla: the LeRobot parquet with pyarrow, its PNG
with TensorFlow and its float TIFF depth with Pillow. The RLDS side is read only through
tensorflow_datasets.
"""

import io
import os
import re
from pathlib import Path
from typing import Any, Dict

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
import pytest  # noqa: E402
import tensorflow as tf  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402
from PIL import Image  # noqa: E402

LEROBOT = Path(os.environ.get("SURGVLA_LEROBOT_DATASET", "")).resolve()
RLDS = Path(os.environ.get("SURGVLA_RLDS_DATASET", "")).resolve()
CONVERTED = Path(os.environ.get("SURGVLA_RLDS_CONVERTED", "")).resolve()
JPEG = Path(os.environ.get("SURGVLA_RLDS_JPEG", "")).resolve()
PULSE = Path(os.environ.get("SURGVLA_RLDS_PULSE", "")).resolve()
NAME, VERSION = "surgvla_benchmark", "1.0.0"


def steps_of(episode):
    """An episode's steps as numpy (decoded images included)."""
    return list(episode["steps"].as_numpy_iterator())


def tfds_episodes(path):
    """Every episode of the RLDS dataset at `path` through tfds, one at a time: (metadata, steps)."""
    # One shard at a time, so episodes come in index order (by default tfds interleaves up to
    # 16 shards, which is fine for training but not for a comparison that streams).
    in_order = tfds.ReadConfig(interleave_cycle_length=1)
    builder = tfds.builder_from_directory(str(path / NAME / VERSION))
    for episode in builder.as_dataset(split="train", read_config=in_order):
        yield {k: v.numpy() for k, v in episode["episode_metadata"].items()}, steps_of(episode)


def lerobot_episodes():
    """The LeRobot dataset's frames, episode by episode, straight from its parquet files:
    (episode metadata row, frame rows, instruction by task index). Streams: the full dataset
    does not fit in memory."""
    tasks = pq.read_table(LEROBOT / "meta" / "tasks.parquet").to_pylist()
    instruction = {t["task_index"]: t["task"] for t in tasks}
    meta = pq.read_table(LEROBOT / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    current, rows = None, []
    for path in sorted((LEROBOT / "data").glob("*/*.parquet")):
        for batch in pq.ParquetFile(path).iter_batches(batch_size=64):
            for row in batch.to_pylist():
                if current is not None and row["episode_index"] != current:
                    yield meta[current], rows, instruction
                    rows = []
                current = row["episode_index"]
                rows.append(row)
    if rows:
        yield meta[current], rows, instruction


@pytest.fixture(scope="module")
def builder():
    return tfds.builder_from_directory(str(RLDS / NAME / VERSION))


def test_dataset_info_and_shards(builder):
    info = builder.info
    assert info.name == NAME
    assert str(info.version) == VERSION
    shards = sorted((RLDS / NAME / VERSION).glob(f"{NAME}-train.tfrecord-*"))
    assert len(shards) >= 2, "the CI dataset rolls shards at 1 MB"
    assert all(re.fullmatch(rf"{NAME}-train\.tfrecord-\d{{5}}-of-{len(shards):05d}", s.name) for s in shards)
    assert info.splits["train"].num_shards == len(shards)
    assert info.splits["train"].num_examples == sum(info.splits["train"].shard_lengths)
    observation = info.features["steps"]["observation"]
    assert observation["image"].shape == (224, 224, 3) and observation["image"].dtype == tf.uint8
    assert observation["depth"].shape == (224, 224, 1) and observation["depth"].dtype == tf.uint16
    assert "millimetres" in observation["depth"].doc.desc
    if "mask" in observation:  # the CI dataset has it (--with-mask), the default one not
        assert observation["mask"].shape == (224, 224, 1)
    assert observation["state"].shape == (7,)
    assert info.features["steps"]["action"].shape == (7,)


def test_tfds_builder_by_name_finds_the_same_dataset(builder):
    by_name = tfds.builder(NAME, data_dir=str(RLDS))
    assert by_name.info.splits["train"].num_examples == builder.info.splits["train"].num_examples
    first = next(iter(by_name.as_dataset(split="train[:1]")))
    assert first["episode_metadata"]["episode_index"].numpy() == 0


def test_every_step_matches_what_was_written(builder):
    count = 0
    for index, ((metadata, steps), (provenance, rows, instruction)) in enumerate(
        zip(tfds_episodes(RLDS), lerobot_episodes(), strict=True)
    ):
        count += 1
        assert metadata["episode_index"] == index
        assert len(steps) == len(rows)
        assert metadata["task_id"].decode() == provenance["surgvla/task_id"]
        assert metadata["level"] == provenance["surgvla/level"]
        assert int(metadata["seed"]) == provenance["surgvla/seed"] % (1 << 64)
        assert bool(metadata["success"]) == provenance["surgvla/success"]
        assert metadata["file_path"].decode() == f"{provenance['surgvla/task_id']}/seed-{int(metadata['seed'])}"
        for t, (step, row) in enumerate(zip(steps, rows)):
            rgb = tf.io.decode_png(row["observation.images.endoscope"]["bytes"]).numpy()
            np.testing.assert_array_equal(step["observation"]["image"], rgb)
            depth_m = np.asarray(Image.open(io.BytesIO(row["observation.images.depth"]["bytes"])), dtype=np.float32)
            # Rounded to the nearest millimetre, halves up (depth is never negative).
            expected_mm = np.floor(depth_m.astype(np.float64) * 1000.0 + 0.5).astype(np.uint16)
            np.testing.assert_array_equal(step["observation"]["depth"][..., 0], expected_mm)
            if "observation.images.mask" in row:
                mask = tf.io.decode_png(row["observation.images.mask"]["bytes"]).numpy()
                np.testing.assert_array_equal(step["observation"]["mask"], mask)
            np.testing.assert_array_equal(step["observation"]["state"], np.float32(row["observation.state"]))
            np.testing.assert_array_equal(step["action"], np.float32(row["action"]))
            np.testing.assert_array_equal(
                step["observation"]["environment_state"], np.float32(row["observation.environment_state"])
            )
            assert step["language_instruction"].decode() == instruction[row["task_index"]]
            last = t == len(rows) - 1
            assert step["is_first"] == (t == 0) and step["is_last"] == last
            assert step["is_terminal"] == (last and bool(metadata["success"]))
            assert step["reward"] == (1.0 if last and metadata["success"] else 0.0)
            assert step["discount"] == 1.0
            assert step["action"][6] in (0.0, 1.0)
    assert count == builder.info.splits["train"].num_examples


def test_collect_and_convert_give_the_same_episodes(builder):
    converted = tfds.builder_from_directory(str(CONVERTED / NAME / VERSION))
    assert converted.info.features.to_json() == builder.info.features.to_json()
    count = 0
    for (metadata, steps), (other_metadata, other_steps) in zip(
        tfds_episodes(RLDS), tfds_episodes(CONVERTED), strict=True
    ):
        assert other_metadata == metadata
        assert len(steps) == len(other_steps)
        for a, b in zip(steps, other_steps):
            tf.nest.map_structure(np.testing.assert_array_equal, a, b)
        count += 1
    assert count == builder.info.splits["train"].num_examples


def test_depth_scale_through_tfds_and_octos_decode_and_resize(builder):
    """OPENVLA.md's two factors: tfds returns millimetres (x 1/1000 for metres); Octo's
    `decode_and_resize` (tf.image.convert_image_dtype to float) gives value / 65535, so
    x 65.535 for metres. Both against the LeRobot dataset's float TIFF depth."""
    text = (RLDS / "OPENVLA.md").read_text()
    assert "divide by 1000" in text and "65.535" in text
    (_, steps), (_, rows, _) = next(zip(tfds_episodes(RLDS), lerobot_episodes()))
    depth_m = np.asarray(Image.open(io.BytesIO(rows[0]["observation.images.depth"]["bytes"])), dtype=np.float32)
    millimetres = steps[0]["observation"]["depth"][..., 0]
    np.testing.assert_allclose(millimetres / 1000.0, depth_m, atol=0.0005 + 1e-6)
    # What Octo's decode_and_resize does with the stored bytes (octo/data/obs_transforms.py:
    # tf.io.decode_image(depth, expand_animations=False, dtype=tf.float32)).
    in_order = tfds.ReadConfig(interleave_cycle_length=1)
    raw = builder.as_dataset(split="train", read_config=in_order, decoders={"steps": tfds.decode.SkipDecoding()})
    encoded = next(iter(raw))["steps"]["observation"]["depth"][0]
    unit = tf.io.decode_image(encoded, expand_animations=False, dtype=tf.float32).numpy()[..., 0]
    assert unit.max() <= 1.0
    np.testing.assert_allclose(unit * 65.535, depth_m, atol=0.0005 + 1e-5)


def test_jpeg_rgb_reads_through_tfds_near_the_png_frames():
    builder = tfds.builder_from_directory(str(JPEG / NAME / VERSION))
    image = builder.info.features["steps"]["observation"]["image"]
    assert image.encoding_format == "jpeg" and image.shape == (224, 224, 3)
    worst = 0.0
    for (_, steps), (_, rows, _) in zip(tfds_episodes(JPEG), lerobot_episodes(), strict=True):
        assert len(steps) == len(rows)
        for step, row in zip(steps, rows):
            png = tf.io.decode_png(row["observation.images.endoscope"]["bytes"]).numpy()
            mean = np.abs(step["observation"]["image"].astype(int) - png.astype(int)).mean()
            worst = max(worst, mean)
            np.testing.assert_array_equal(step["action"], np.float32(row["action"]))
    # surgvla's --verify tolerance (LOSSY_RGB_MEAN_TOLERANCE) is 6 levels; quality 95 keeps far
    # closer.
    assert worst < 3.0, worst
    # OpenVLA reads the encoded bytes and decodes them with TensorFlow.
    raw = builder.as_dataset(split="train", decoders={"steps": tfds.decode.SkipDecoding()})
    encoded = next(iter(raw))["steps"]["observation"]["image"][0]
    decoded = tf.io.decode_image(encoded, expand_animations=False, dtype=tf.uint8)
    assert decoded.shape == (224, 224, 3)
    # A fraction of the PNG dataset's size.
    size = lambda root: sum(p.stat().st_size for p in (root / NAME / VERSION).glob("*.tfrecord*"))
    assert size(JPEG) < size(CONVERTED)


def openvla_snippets(root):
    """The Python blocks of `root`'s OPENVLA.md: the config entry and the standardize transform."""
    text = (root / "OPENVLA.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 2, "OPENVLA.md has the config entry and the transform"
    return blocks


class StateEncoding:
    POS_EULER = 1


class ActionEncoding:
    EEF_POS = 1


@pytest.mark.parametrize("root", [RLDS, PULSE], ids=["absolute", "pulse"])
def test_openvla_standardisation_yields_what_openvla_expects(root):
    config_block, transform_block = openvla_snippets(root)
    namespace = {
        "OXE_DATASET_CONFIGS": {},
        "OXE_STANDARDIZATION_TRANSFORMS": {},
        "StateEncoding": StateEncoding,
        "ActionEncoding": ActionEncoding,
        "Dict": Dict,
        "Any": Any,
        "tf": tf,
    }
    exec(config_block, namespace)
    exec(transform_block, namespace)
    config = namespace["OXE_DATASET_CONFIGS"][NAME]
    standardize = namespace["OXE_STANDARDIZATION_TRANSFORMS"][NAME]

    # What OpenVLA does (prismatic/vla/datasets/rlds/dataset.py, dlimp's from_rlds): read with
    # tfds.builder(name, data_dir), keep the steps encoded, broadcast the metadata.
    builder = tfds.builder(NAME, data_dir=str(root))
    dataset = builder.as_dataset(split="train[:95%]", decoders={"steps": tfds.decode.SkipDecoding()})

    def broadcast(i, traj):
        steps = traj.pop("steps")
        length = tf.shape(tf.nest.flatten(steps)[0])[0]
        metadata = tf.nest.map_structure(lambda x: tf.repeat(x, length), traj)
        return {**steps, "traj_metadata": metadata, "_len": tf.repeat(length, length), "_traj_index": tf.repeat(i, length)}

    def restructure(traj):
        traj = standardize(traj)
        length = tf.shape(traj["action"])[0]
        old = traj["observation"]
        image_key = config["image_obs_keys"]["primary"]
        proprio = tf.concat(
            [tf.zeros((length, 1), tf.float32) if k is None else tf.cast(old[k], tf.float32) for k in config["state_obs_keys"]],
            axis=1,
        )
        return {
            "observation": {"image_primary": old[image_key], "proprio": proprio},
            "task": {"language_instruction": traj["language_instruction"]},
            "action": tf.cast(traj["action"], tf.float32),
        }

    actions = []
    for traj in dataset.enumerate().map(broadcast).map(restructure).as_numpy_iterator():
        length = traj["action"].shape[0]
        assert traj["action"].shape == (length, 7) and traj["action"].dtype == np.float32
        assert set(np.unique(traj["action"][:, 6])) <= {0.0, 1.0}, "absolute gripper, 1 open / 0 closed"
        # POS_EULER: EEF xyz + rpy (6), a pad (1), the gripper state (1).
        assert traj["observation"]["proprio"].shape == (length, 8)
        assert traj["task"]["language_instruction"].shape == (length,)
        assert all(s for s in traj["task"]["language_instruction"])
        image = tf.io.decode_image(traj["observation"]["image_primary"][0], expand_animations=False).numpy()
        assert image.shape == (224, 224, 3) and image.dtype == np.uint8
        actions.append(traj["action"])
    assert actions, "OpenVLA's train[:95%] split holds episodes"
    # BOUNDS_Q99 needs spread in each delta over the dataset.
    actions = np.concatenate(actions)
    q01, q99 = np.quantile(actions[:, :6], [0.01, 0.99], axis=0)
    assert np.all(q99[:3] > q01[:3]), "translation deltas vary"


def test_the_cards_loading_snippet_runs_as_written(monkeypatch):
    """The dataset card's "Loading" code block, run from the dataset's folder as it says."""
    card = (RLDS / "README.md").read_text()
    snippet = card.split("## Loading", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(RLDS)
    scope = {}
    exec(snippet, scope)
    assert tuple(scope["image"].shape) == (224, 224, 3)
    assert tuple(scope["action"].shape) == (7,)
