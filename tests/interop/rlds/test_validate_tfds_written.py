"""`surgvla validate` and `info` on an RLDS dataset written by tensorflow_datasets itself, laid
out as Open X-Embodiment datasets are (other keys and shapes than ours: two cameras, an 8-D
state, bool flags, a language instruction): valid as written, and defects made in it (a flipped
byte, a wrong shardLengths, an episode whose is_last is missing on the last step) are named.

SURGVLA_BIN is the surgvla binary.
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import tensorflow as tf  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")


class OxeLike(tfds.core.GeneratorBasedBuilder):
    """Three episodes in the Open X-Embodiment RLDS layout."""

    VERSION = tfds.core.Version("1.0.0")

    def _info(self):
        step = {
            "observation": {
                "image": tfds.features.Image(shape=(32, 40, 3)),
                "wrist_image": tfds.features.Image(shape=(16, 16, 3)),
                "state": tfds.features.Tensor(shape=(8,), dtype=np.float32),
            },
            "action": tfds.features.Tensor(shape=(7,), dtype=np.float32),
            "reward": tfds.features.Scalar(dtype=np.float32),
            "discount": tfds.features.Scalar(dtype=np.float32),
            "is_first": tfds.features.Scalar(dtype=np.bool_),
            "is_last": tfds.features.Scalar(dtype=np.bool_),
            "is_terminal": tfds.features.Scalar(dtype=np.bool_),
            "language_instruction": tfds.features.Text(),
        }
        return tfds.core.DatasetInfo(
            builder=self,
            features=tfds.features.FeaturesDict({
                "steps": tfds.features.Dataset(step),
                "episode_metadata": {"file_path": tfds.features.Text()},
            }),
        )

    def _split_generators(self, dl_manager):
        return {"train": self._generate_examples()}

    def _generate_examples(self):
        rng = np.random.default_rng(0)
        for episode in range(3):
            n = 5 + episode
            steps = [{
                "observation": {
                    "image": rng.integers(0, 255, (32, 40, 3), dtype=np.uint8),
                    "wrist_image": rng.integers(0, 255, (16, 16, 3), dtype=np.uint8),
                    "state": rng.standard_normal(8).astype(np.float32),
                },
                "action": rng.standard_normal(7).astype(np.float32),
                "reward": float(i == n - 1),
                "discount": 1.0,
                "is_first": i == 0,
                "is_last": i == n - 1,
                "is_terminal": i == n - 1,
                "language_instruction": "put the cup on the plate",
            } for i in range(n)]
            yield f"episode_{episode}", {"steps": steps, "episode_metadata": {"file_path": f"ep{episode}"}}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("tfds")
    builder = OxeLike(data_dir=str(data_dir))
    builder.download_and_prepare()
    return Path(builder.data_dir)


def validate(root: Path):
    done = subprocess.run([BIN, "validate", str(root), "--json"], capture_output=True, text=True)
    return done.returncode, json.loads(done.stdout) if done.stdout else None, done.stderr


def test_tfds_written_dataset_is_valid_and_described(written):
    code, report, err = validate(written)
    assert code == 0, (report, err)
    assert report["format"] == "rlds" and report["episodes"] == 3 and report["frames"] == 18
    code, report, err = validate(written.parent.parent)  # the data directory above <name>/<version>
    assert code == 0, (report, err)
    done = subprocess.run([BIN, "info", str(written), "--json"], capture_output=True, text=True)
    info = json.loads(done.stdout)
    shapes = {f["name"]: f["shape"] for f in info["features"]}
    assert shapes["steps/observation/state"] == [8], shapes
    assert shapes["steps/observation/wrist_image"] == [16, 16, 3], shapes


def shard(root: Path) -> Path:
    return next(root.glob("*.tfrecord-*"))


def copied(written, tmp_path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(written, target)
    return target


def errors(root):
    code, report, err = validate(root)
    assert code == 1, (report, err)
    return report["errors"]


def test_a_flipped_byte_is_a_crc_error(written, tmp_path):
    root = copied(written, tmp_path)
    data = bytearray(shard(root).read_bytes())
    data[len(data) // 2] ^= 0x20
    shard(root).write_bytes(bytes(data))
    assert any(e["check"] == "crc" for e in errors(root))


def test_wrong_shard_lengths_are_named(written, tmp_path):
    root = copied(written, tmp_path)
    info_path = root / "dataset_info.json"
    info = json.loads(info_path.read_text())
    info["splits"][0]["shardLengths"] = ["4"]
    info_path.write_text(json.dumps(info))
    assert any(e["check"] == "shard_lengths" for e in errors(root))


def test_a_missing_is_last_is_named(written, tmp_path):
    root = copied(written, tmp_path)
    records = list(tf.data.TFRecordDataset(str(shard(root))).as_numpy_iterator())
    example = tf.train.Example.FromString(records[1])
    flags = example.features.feature["steps/is_last"].int64_list.value
    flags[len(flags) - 1] = 0
    records[1] = example.SerializeToString()
    with tf.io.TFRecordWriter(str(shard(root))) as writer:
        for record in records:
            writer.write(record)
    found = [e for e in errors(root) if e["check"] == "flags"]
    assert found and found[0]["episode"] == 1, found


def test_tfds_written_dataset_converts_to_lerobot(written, tmp_path):
    """RLDS -> LeRobot for a dataset tensorflow_datasets wrote: `--fps` is required (exit 2
    without), the output is verified frame by frame and valid, and its values are the ones
    tensorflow_datasets reads (images pass through as the PNG bytes TFDS stored)."""
    import io

    import pyarrow.parquet as pq
    from PIL import Image

    out = tmp_path / "lerobot"
    done = subprocess.run([BIN, "convert", str(written), "--to", "lerobot", "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 2 and "--fps" in done.stderr, done.stderr
    done = subprocess.run(
        [BIN, "convert", str(written), "--to", "lerobot", "--fps", "10", "--out", str(out), "--verify"],
        capture_output=True, text=True,
    )
    assert done.returncode == 0, done.stderr
    code, report, err = validate(out)
    assert code == 0, (report, err)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["fps"] == 10 and info["robot_type"] == "unknown"
    table = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    builder = tfds.builder_from_directory(str(written))
    row = 0
    for episode in builder.as_dataset(split="train", shuffle_files=False, read_config=tfds.ReadConfig(interleave_cycle_length=1)):
        for step in episode["steps"]:
            assert np.array_equal(np.array(table["observation.state"][row], np.float32), step["observation"]["state"].numpy())
            assert np.array_equal(np.array(table["action"][row], np.float32), step["action"].numpy())
            assert table["reward"][row] == pytest.approx(float(step["reward"].numpy()))
            pixels = np.array(Image.open(io.BytesIO(table["observation.images.image"][row]["bytes"])))
            assert np.array_equal(pixels, step["observation"]["image"].numpy())
            row += 1
    assert row == len(table["index"]) == 18


def test_tfds_written_dataset_round_trips_through_lerobot_back_to_rlds(written, tmp_path):
    """RLDS (tfds) -> LeRobot -> RLDS by surgvla: tensorflow_datasets loads the result, with the
    same steps as the dataset it wrote."""
    lerobot, rlds = tmp_path / "lerobot", tmp_path / "rlds"
    for source, to, target in [(written, "lerobot", lerobot), (lerobot, "rlds", rlds)]:
        done = subprocess.run(
            [BIN, "convert", str(source), "--to", to, "--fps", "10", "--out", str(target), "--verify"],
            capture_output=True, text=True,
        )
        assert done.returncode == 0, done.stderr
    code, report, err = validate(rlds)
    assert code == 0, (report, err)
    config = tfds.ReadConfig(interleave_cycle_length=1)
    original = tfds.builder_from_directory(str(written)).as_dataset(split="train", shuffle_files=False, read_config=config)
    again = tfds.builder_from_directory(str(next(rlds.glob("*/*")))).as_dataset(split="train", shuffle_files=False, read_config=config)
    count = 0
    for a, b in zip(original, again):
        for x, y in zip(a["steps"], b["steps"]):
            assert np.array_equal(x["observation"]["image"].numpy(), y["observation"]["image"].numpy())
            assert np.array_equal(x["observation"]["state"].numpy(), y["observation"]["state"].numpy())
            assert np.array_equal(x["action"].numpy(), y["action"].numpy())
            assert bool(x["is_first"].numpy()) == bool(y["is_first"].numpy())
            assert x["language_instruction"].numpy() == y["language_instruction"].numpy()
            count += 1
    assert count == 18
