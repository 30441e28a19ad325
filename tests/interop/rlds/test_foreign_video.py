"""RLDS converted by surgvla from video datasets lerobot 0.6.1 wrote (AV1 with lerobot's
defaults, and libx264 H.264 with B-frames), read by the real tensorflow_datasets: every frame of
every camera equals lerobot's own decoding within the YUV -> RGB tolerance, and OpenVLA's way of
reading (tfds.builder by name, steps left encoded, images decoded and resized with TensorFlow)
yields them.

SURGVLA_FOREIGN_VIDEO_OUT is the folder tests/interop/lerobot/test_convert_lerobot_video.py
filled: <codec>/rlds (the conversion) and <codec>/lerobot_frames.npz (lerobot's frames).
"""

import os
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import tensorflow as tf  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402

OUT = Path(os.environ.get("SURGVLA_FOREIGN_VIDEO_OUT", "")).resolve()
NAME, VERSION = "surgvla_benchmark", "1.0.0"
# The same tolerance as the lerobot-side test: 8-bit levels in any byte.
RGB_TOLERANCE = 3
CAMERAS = {"observation_images_top": "top", "observation_images_wrist": "wrist"}


@pytest.fixture(params=["av1", "h264"])
def converted(request):
    root = OUT / request.param
    if not (root / "rlds").is_dir():
        pytest.fail(f"{root}/rlds is missing: run tests/interop/lerobot/test_convert_lerobot_video.py first")
    return root


def test_tfds_reads_lerobots_frames(converted):
    theirs = np.load(converted / "lerobot_frames.npz")
    in_order = tfds.ReadConfig(interleave_cycle_length=1)
    builder = tfds.builder_from_directory(str(converted / "rlds" / NAME / VERSION))
    ours = {key: [] for key in CAMERAS.values()}
    for episode in builder.as_dataset(split="train", read_config=in_order):
        for step in episode["steps"].as_numpy_iterator():
            for key in CAMERAS.values():
                ours[key].append(step["observation"][key])
    for npz_key, key in CAMERAS.items():
        frames = np.stack(ours[key])
        assert frames.shape == theirs[npz_key].shape, (key, frames.shape, theirs[npz_key].shape)
        worst = int(np.abs(frames.astype(int) - theirs[npz_key].astype(int)).max())
        assert worst <= RGB_TOLERANCE, (key, worst)


def test_openvlas_way_of_reading_yields_the_frames(converted):
    # prismatic/vla/datasets/rlds/dataset.py through dlimp: tfds.builder(name, data_dir), the
    # steps kept encoded, then each image decoded and resized (decode_and_resize).
    builder = tfds.builder(NAME, data_dir=str(converted / "rlds"))
    dataset = builder.as_dataset(split="train", decoders={"steps": tfds.decode.SkipDecoding()})
    seen = 0
    for traj in dataset:
        encoded = traj["steps"]["observation"]["top"]
        for image in encoded:
            decoded = tf.io.decode_image(image, expand_animations=False, dtype=tf.uint8)
            resized = tf.image.resize(decoded, (224, 224), method="lanczos3", antialias=True)
            assert decoded.shape == (48, 64, 3) and resized.shape == (224, 224, 3)
            seen += 1
        assert traj["steps"]["action"].shape[1] == 6
        assert all(s for s in traj["steps"]["language_instruction"].numpy())
    assert seen == 14 + 17 + 20
