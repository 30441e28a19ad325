"""`surgvla convert` on video datasets written by lerobot 0.6.1 itself (AV1 with lerobot's
defaults, and H.264 through PyAV's libx264, which writes High profile with B-frames): the
frames surgvla decodes are the frames lerobot's own loader gives, within the YUV -> RGB
tolerance below; the image-mode LeRobot conversion loads in lerobot with those frames; the
RLDS conversion verifies (`--verify`) and is left for the tfds test
(tests/interop/rlds/test_foreign_video.py) when SURGVLA_FOREIGN_VIDEO_OUT names a folder.

SURGVLA_BIN is the surgvla binary.
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.configs.video import RGBEncoderConfig  # noqa: E402
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
# surgvla's integer BT.601 conversion against lerobot's decoder (torchcodec / FFmpeg's
# swscale): at most this many 8-bit levels apart in any byte (measured: see README).
RGB_TOLERANCE = 3
CAMERAS = {"observation.images.top": (48, 64), "observation.images.wrist": (32, 40)}


def scene(t: int, height: int, width: int, phase: int) -> np.ndarray:
    """A smooth moving picture (what a camera sees), so the codec keeps it close."""
    y, x = np.mgrid[0:height, 0:width]
    image = np.stack(
        [(x * 3 + t * 5 + phase) % 256, (y * 4 + t * 2) % 256, ((x + y) * 2 + phase) % 256], axis=-1
    )
    return image.astype(np.uint8)


def make(root: Path, vcodec: str | None) -> Path:
    """Three episodes of a two-camera arm; AV1 with lerobot's defaults when `vcodec` is None."""
    features = {
        "observation.state": {"dtype": "float32", "shape": (6,), "names": [f"j{i}" for i in range(6)]},
        "action": {"dtype": "float32", "shape": (6,), "names": [f"a{i}" for i in range(6)]},
    }
    for key, (height, width) in CAMERAS.items():
        features[key] = {"dtype": "video", "shape": (height, width, 3), "names": ["height", "width", "channels"]}
    encoder = RGBEncoderConfig(vcodec=vcodec) if vcodec else None
    dataset = LeRobotDataset.create(
        "someone/two-cameras", fps=30, features=features, root=root, robot_type="so100", use_videos=True,
        rgb_encoder=encoder,
    )
    rng = np.random.default_rng(1)
    for episode, task in enumerate(["pick the cube", "stack the cubes", "pick the cube"]):
        for t in range(14 + 3 * episode):
            frame = {
                "observation.state": rng.standard_normal(6).astype(np.float32),
                "action": rng.standard_normal(6).astype(np.float32),
                "task": task,
            }
            for phase, (key, (height, width)) in enumerate(CAMERAS.items()):
                frame[key] = scene(t + 40 * episode, height, width, 70 * phase)
            dataset.add_frame(frame)
        dataset.save_episode()
    dataset.finalize()
    return root


def surgvla(*args) -> subprocess.CompletedProcess:
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)


def backends() -> list[str]:
    """lerobot's video decoders here: PyAV, and torchcodec (its default) where it loads (it
    needs the system's FFmpeg libraries). .ci/run installs them and sets
    SURGVLA_REQUIRE_TORCHCODEC=1, so there a torchcodec that does not load fails the test
    instead of being left out."""
    try:
        import torchcodec.decoders  # noqa: F401

        return ["pyav", "torchcodec"]
    except Exception:
        if os.environ.get("SURGVLA_REQUIRE_TORCHCODEC") == "1":
            raise
        return ["pyav"]


def frames(root: Path, backend: str | None = None) -> dict[str, np.ndarray]:
    """Every frame of every camera as lerobot's loader gives it, as uint8 HWC."""
    dataset = LeRobotDataset("someone/two-cameras", root=root, video_backend=backend)
    out = {key: [] for key in CAMERAS}
    for i in range(len(dataset)):
        item = dataset[i]
        for key in CAMERAS:
            out[key].append(np.round(item[key].numpy().transpose(1, 2, 0) * 255).astype(np.uint8))
    return {key: np.stack(value) for key, value in out.items()}


@pytest.fixture(scope="module", params=["av1", "h264"])
def written(request, tmp_path_factory):
    root = tmp_path_factory.mktemp("lerobot-written") / request.param
    make(root, None if request.param == "av1" else "h264")
    info = json.loads((root / "meta/info.json").read_text())
    codec = info["features"]["observation.images.top"]["info"]["video.codec"]
    return request.param, codec, root


def test_the_written_datasets_use_the_codecs_under_test(written):
    name, codec, root = written
    assert codec == ("av1" if name == "av1" else "h264"), codec
    if name == "h264":
        import av

        # libx264's defaults: High profile with B-frames (frames presented out of decode order).
        video = next(root.glob("videos/observation.images.top/**/*.mp4"))
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            assert stream.codec_context.profile == "High"
            packets = [p for p in container.demux(stream) if p.size]
            assert any(p.pts != p.dts for p in packets), "expected B-frames"


def test_image_mode_conversion_holds_lerobots_frames(written, tmp_path):
    name, _, root = written
    out = tmp_path / "images"
    done = surgvla("convert", root, "--to", "lerobot", "--decode", "--out", out, "--verify")
    assert done.returncode == 0, done.stderr
    info = json.loads((out / "meta/info.json").read_text())
    assert all(info["features"][key]["dtype"] == "image" for key in CAMERAS), info["features"]
    ours = frames(out)
    for backend in backends():
        theirs = frames(root, backend)
        worst = {key: int(np.abs(theirs[key].astype(int) - ours[key].astype(int)).max()) for key in CAMERAS}
        print(f"{name}: largest RGB difference from lerobot's decoding with {backend}: {worst}")
        assert all(w <= RGB_TOLERANCE for w in worst.values()), (backend, worst)
    assert surgvla("validate", out).returncode == 0
    if os.environ.get("SURGVLA_FOREIGN_VIDEO_OUT"):
        keep = Path(os.environ["SURGVLA_FOREIGN_VIDEO_OUT"]) / name
        keep.mkdir(parents=True, exist_ok=True)
        np.savez(keep / "lerobot_frames.npz", **{k.replace(".", "_"): v for k, v in theirs.items()})


def test_rlds_conversion_verifies(written, tmp_path):
    name, _, root = written
    base = Path(os.environ["SURGVLA_FOREIGN_VIDEO_OUT"]) / name if os.environ.get("SURGVLA_FOREIGN_VIDEO_OUT") else tmp_path
    out = base / "rlds"
    shutil.rmtree(out, ignore_errors=True)
    done = surgvla("convert", root, "--to", "rlds", "--out", out, "--verify")
    assert done.returncode == 0, done.stderr
    assert "verified" in done.stdout + done.stderr


def test_copying_keeps_av1_and_refuses_b_frames_by_name(written, tmp_path):
    name, _, root = written
    done = surgvla("convert", root, "--to", "lerobot", "--out", tmp_path / "copy", "--verify")
    if name == "av1":
        assert done.returncode == 0, done.stderr
    else:
        assert done.returncode != 0 and "B-frames" in done.stderr, done.stderr
        # Re-encoding decodes them; lerobot loads the result, every camera as AV1 video.
        out = tmp_path / "av1"
        again = surgvla("convert", root, "--to", "lerobot", "--video", "av1", "--out", out, "--verify")
        assert again.returncode == 0, again.stderr
        info = json.loads((out / "meta/info.json").read_text())
        assert all(info["features"][key]["info"]["video.codec"] == "av1" for key in CAMERAS)
        theirs, ours = frames(root), frames(out)
        for key in CAMERAS:
            mean = np.abs(theirs[key].astype(int) - ours[key].astype(int)).mean()
            assert mean < 6.0, (key, mean)


def test_merge_exact_stats_come_from_every_decoded_frame(written, tmp_path):
    name, _, root = written
    out = tmp_path / "merged"
    done = surgvla("merge", root, root, "--exact-stats", "--out", out)
    if name == "h264":
        # B-frames cannot be copied: the user's error, named, with nothing left behind.
        assert done.returncode == 2 and "B-frames" in done.stderr, done.stderr
        assert not out.exists()
        return
    assert done.returncode == 0, done.stderr
    assert surgvla("validate", out).returncode == 0
    stats = json.loads((out / "meta/stats.json").read_text())
    # surgvla's own decoding of the frames (image mode), and lerobot's.
    images = tmp_path / "images"
    assert surgvla("convert", root, "--to", "lerobot", "--decode", "--out", images).returncode == 0
    ours, theirs = frames(images, "pyav"), frames(root, "pyav")
    for key in CAMERAS:
        entry = stats[key]
        assert entry["count"] == [2 * len(ours[key])], entry["count"]
        mean, std = np.array(entry["mean"]).reshape(3), np.array(entry["std"]).reshape(3)
        # Exact over every decoded frame.
        pixels = ours[key].reshape(-1, 3) / 255.0
        np.testing.assert_allclose(mean, pixels.mean(axis=0), atol=1e-6)
        np.testing.assert_allclose(std, pixels.std(axis=0), atol=1e-6)
        np.testing.assert_allclose(np.array(entry["min"]).reshape(3), pixels.min(axis=0), atol=1e-6)
        np.testing.assert_allclose(np.array(entry["max"]).reshape(3), pixels.max(axis=0), atol=1e-6)
        # Against lerobot's own decoding (swscale's conversion): the means within 0.01.
        np.testing.assert_allclose(mean, (theirs[key].reshape(-1, 3) / 255.0).mean(axis=0), atol=0.01)
