"""`surgvla validate` and `info` on datasets written by lerobot 0.6.1 itself (other robots'
features and shapes, image and video mode): the good ones are valid, and defects made in them
with pyarrow (the kinds lerobot's loader accepts silently) are each named.

SURGVLA_BIN is the surgvla binary.
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")


def make(root: Path, video: bool) -> Path:
    """Three episodes of an ALOHA-like robot: 14-D state and action, 6 efforts, one camera."""
    camera = {"dtype": "video" if video else "image", "shape": (48, 64, 3), "names": ["height", "width", "channels"]}
    features = {
        "observation.state": {"dtype": "float32", "shape": (14,), "names": [f"j{i}" for i in range(14)]},
        "observation.effort": {"dtype": "float32", "shape": (6,), "names": None},
        "action": {"dtype": "float32", "shape": (14,), "names": [f"a{i}" for i in range(14)]},
        "observation.images.cam_high": camera,
    }
    dataset = LeRobotDataset.create("someone/aloha-like", fps=50, features=features, root=root, robot_type="aloha", use_videos=video)
    rng = np.random.default_rng(0)
    for episode, task in enumerate(["fold the towel", "open the drawer", "fold the towel"]):
        for _ in range(12 + episode):
            dataset.add_frame({
                "observation.state": rng.standard_normal(14).astype(np.float32),
                "observation.effort": rng.standard_normal(6).astype(np.float32),
                "action": rng.standard_normal(14).astype(np.float32),
                "observation.images.cam_high": rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
                "task": task,
            })
        dataset.save_episode()
    dataset.finalize()
    return root


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    return make(tmp_path_factory.mktemp("foreign") / "images", video=False)


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    return make(tmp_path_factory.mktemp("foreign") / "videos", video=True)


def validate(root: Path, *flags: str):
    done = subprocess.run([BIN, "validate", str(root), "--json", *flags], capture_output=True, text=True)
    return done.returncode, json.loads(done.stdout) if done.stdout else None, done.stderr


def copy(root: Path, tmp_path: Path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(root, target)
    return target


def rewrite(path: Path, change):
    table = pq.read_table(path)
    pq.write_table(change(table), path, compression="zstd")


def test_lerobot_written_datasets_are_valid(images, videos):
    for root in [images, videos]:
        code, report, err = validate(root)
        assert code == 0, (root, report, err)
        assert report["valid"] and report["format"] == "lerobot-v3.0"
        assert report["episodes"] == 3 and report["frames"] == 39
    # Images and video frames are decoded (lerobot's AV1): no warning of the format's checks,
    # and no lint error (its warnings are true: these synthetic episodes are 13 frames long).
    for root in [images, videos]:
        assert validate(root, "--no-lint")[1]["warnings"] == []
        assert all(line["status"] != "error" for line in validate(root)[1]["lint"])


def test_a_damaged_video_sample_is_named_with_its_episode(videos, tmp_path):
    import av

    root = copy(videos, tmp_path)
    video = next(root.glob("videos/observation.images.cam_high/**/*.mp4"))
    with av.open(str(video)) as container:
        packets = [(p.pos, p.size) for p in container.demux(video=0) if p.size]
    # The 20th sample (episode 1, which starts at frame 12) overwritten.
    pos, size = packets[20]
    data = bytearray(video.read_bytes())
    data[pos + 2 : pos + size] = b"\xff" * (size - 2)
    video.write_bytes(bytes(data))
    found = [e for e in errors(root) if e["check"] == "video-decode"]
    assert found and found[0]["episode"] == 1 and found[0]["file"].endswith(".mp4"), found
    # --quick decodes each episode's first frame only: episode 1's first frame is intact.
    done = subprocess.run([BIN, "validate", str(root), "--quick", "--json"], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout


def test_info_describes_a_lerobot_written_dataset(images):
    done = subprocess.run([BIN, "info", str(images), "--json"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout)
    assert info["fps"] == 50 and info["robot_type"] == "aloha"
    assert info["tasks"] == {"fold the towel": 2, "open the drawer": 1}
    shapes = {f["name"]: f["shape"] for f in info["features"]}
    assert shapes["observation.state"] == [14] and shapes["observation.images.cam_high"] == [48, 64, 3]


def test_a_byte_differently_rewritten_dataset_is_valid(images, tmp_path):
    root = copy(images, tmp_path)
    rewrite(root / "data/chunk-000/file-000.parquet", lambda t: t)
    code, report, err = validate(root)
    assert code == 0, (report, err)


def errors(root):
    code, report, err = validate(root)
    assert code == 1, (report, err)
    return report["errors"]


def test_shifted_from_to_is_named(images, tmp_path):
    root = copy(images, tmp_path)
    path = root / "meta/episodes/chunk-000/file-000.parquet"

    def shift(table):
        for name in ["dataset_from_index", "dataset_to_index"]:
            index = table.schema.get_field_index(name)
            table = table.set_column(index, name, pa.array([v + 1 for v in table[name].to_pylist()], pa.int64()))
        return table

    rewrite(path, shift)
    assert any(e["check"] == "from_to" and e["file"].startswith("meta/episodes") for e in errors(root))


def test_a_nan_in_one_frame_is_named(images, tmp_path):
    root = copy(images, tmp_path)

    def poison(table):
        values = table["observation.effort"].to_pylist()
        values[20][3] = float("nan")
        index = table.schema.get_field_index("observation.effort")
        field = table.schema.field(index)
        return table.set_column(index, field, pa.array(values, field.type))

    rewrite(root / "data/chunk-000/file-000.parquet", poison)
    found = [e for e in errors(root) if e["check"] == "finite"]
    assert found and found[0]["episode"] == 1 and found[0]["frame"] == 8, found


def test_an_rgba_frame_is_named(images, tmp_path):
    import io
    from PIL import Image

    root = copy(images, tmp_path)

    def rgba(table):
        values = table["observation.images.cam_high"].to_pylist()
        buffer = io.BytesIO()
        Image.new("RGBA", (64, 48)).save(buffer, format="PNG")
        values[5]["bytes"] = buffer.getvalue()
        index = table.schema.get_field_index("observation.images.cam_high")
        field = table.schema.field(index)
        return table.set_column(index, field, pa.array(values, field.type))

    rewrite(root / "data/chunk-000/file-000.parquet", rgba)
    found = [e for e in errors(root) if e["check"] == "image"]
    assert found and "RGBA" in found[0]["message"] and found[0]["frame"] == 5, found


def test_tasks_without_their_pandas_index_are_named(images, tmp_path):
    root = copy(images, tmp_path)
    path = root / "meta/tasks.parquet"
    table = pq.read_table(path).replace_schema_metadata(None)
    pq.write_table(table, path)
    assert any(e["check"] == "tasks" for e in errors(root))


def test_a_video_span_past_its_file_is_named(videos, tmp_path):
    root = copy(videos, tmp_path)
    path = root / "meta/episodes/chunk-000/file-000.parquet"
    name = "videos/observation.images.cam_high/to_timestamp"

    def stretch(table):
        index = table.schema.get_field_index(name)
        return table.set_column(index, name, pa.array([v + 10.0 for v in table[name].to_pylist()], pa.float64()))

    rewrite(path, stretch)
    assert any(e["check"] == "video" for e in errors(root))


def through_v21(source: Path, tmp_path: Path) -> Path:
    """`source` converted to v2.1 and back to v3.0, each step `--verify`ed; the v3.0 copy."""
    v21, v30 = tmp_path / "v21", tmp_path / "v30"
    for origin, target, version in [(source, v21, "2.1"), (v21, v30, "3.0")]:
        done = subprocess.run(
            [BIN, "convert", str(origin), "--to", "lerobot", "--lerobot-version", version, "--out", str(target), "--verify"],
            capture_output=True, text=True,
        )
        assert done.returncode == 0, done.stderr
        assert "verified" in done.stdout
    return v30


def test_lerobot_written_dataset_converts_through_v21_unchanged(images, tmp_path):
    """Another robot's features (14-D state, efforts, a camera) pass through `convert`: v3.0 ->
    v2.1 -> v3.0, verified by surgvla, loaded by lerobot with the same values, and the camera's
    PNG bytes unchanged (no re-encoding)."""
    import torch

    v30 = through_v21(images, tmp_path)
    code, report, err = validate(v30)
    assert code == 0, (report, err)
    original = LeRobotDataset("someone/aloha-like", root=images)
    converted = LeRobotDataset("someone/aloha-like", root=v30)
    assert len(converted) == len(original) and converted.num_episodes == original.num_episodes
    assert converted.meta.robot_type == "aloha" and converted.fps == 50
    for i in range(len(original)):
        a, b = original[i], converted[i]
        assert a["task"] == b["task"]
        for key in ["observation.state", "observation.effort", "action", "observation.images.cam_high", "timestamp", "index"]:
            assert torch.equal(a[key], b[key]), (i, key)
    column = "observation.images.cam_high"
    before = pq.read_table(images / "data/chunk-000/file-000.parquet")[column].to_pylist()
    after = pq.read_table(v30 / "data/chunk-000/file-000.parquet")[column].to_pylist()
    assert [x["bytes"] for x in before] == [x["bytes"] for x in after]


def test_other_features_go_to_rlds_and_the_camera_formats_once_one_is_named(images, tmp_path):
    """RLDS holds every feature; zarr and MCAP, built around one camera, refuse without
    --camera (naming the flag and the dataset's image features, writing nothing) and with it
    keep `observation.effort` (zarr: an array under its key; MCAP: a channel of its own)."""
    done = subprocess.run(
        [BIN, "convert", str(images), "--to", "rlds", "--out", str(tmp_path / "rlds"), "--verify"],
        capture_output=True, text=True,
    )
    assert done.returncode == 0, done.stderr
    code, report, err = validate(tmp_path / "rlds")
    assert code == 0, (report, err)
    for to in ["zarr", "mcap"]:
        done = subprocess.run([BIN, "convert", str(images), "--to", to, "--out", str(tmp_path / to)], capture_output=True, text=True)
        assert done.returncode == 2, done.stderr
        assert "--camera KEY" in done.stderr and "observation.images.cam_high" in done.stderr, done.stderr
        assert not (tmp_path / to).exists()
        camera = ["--camera", "observation.images.cam_high"]
        done = subprocess.run([BIN, "convert", str(images), "--to", to, *camera, "--out", str(tmp_path / to)], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        code, report, err = validate(tmp_path / to)
        assert code == 0, (report, err)
    assert (tmp_path / "zarr/data/observation.effort/.zarray").is_file()
    assert b"/observation/effort" in (tmp_path / "mcap/episode_000000.mcap").read_bytes()


def test_lerobot_written_video_converts_and_merges_without_reencoding(videos, tmp_path):
    """A video dataset lerobot wrote (AV1 through PyAV) goes v3.0 -> v2.1 -> v3.0 and is merged
    with itself: the video samples are copied, never decoded and encoded again, so lerobot
    decodes exactly the original frames; its statistics are merged from lerobot's per-episode
    summaries (counts summed)."""
    import torch

    v30, merged = through_v21(videos, tmp_path), tmp_path / "merged"
    done = subprocess.run([BIN, "merge", str(videos), str(v30), "--out", str(merged)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    for root in [v30, merged]:
        code, report, err = validate(root)
        assert code == 0, (report, err)
    camera = "observation.images.cam_high"
    original = LeRobotDataset("someone/aloha-like", root=videos, video_backend="pyav")
    converted = LeRobotDataset("someone/aloha-like", root=v30, video_backend="pyav")
    both = LeRobotDataset("someone/aloha-like", root=merged, video_backend="pyav")
    assert converted.features[camera]["dtype"] == "video"
    assert both.num_episodes == 2 * original.num_episodes and len(both) == 2 * len(original)
    for i in range(len(original)):
        a = original[i]
        for b in [converted[i], both[i], both[len(original) + i]]:
            assert torch.equal(a[camera], b[camera]), i
            assert torch.equal(a["action"], b["action"]), i
    stats = json.loads((merged / "meta/stats.json").read_text())[camera]
    assert stats["count"] == [2 * len(original)]
    assert np.array(stats["mean"]).shape == (3, 1, 1)
    # A format that needs pixels gets the video decoded (test_convert_lerobot_video.py
    # compares the frames with lerobot's).
    done = subprocess.run(
        [BIN, "convert", str(videos), "--to", "rlds", "--out", str(tmp_path / "rlds"), "--verify"],
        capture_output=True, text=True,
    )
    assert done.returncode == 0, done.stderr
