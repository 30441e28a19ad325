"""surgvla's LeRobot video mode (AV1 or H.264 MP4), loaded by the real lerobot 0.6.1 loader (PyAV).

SURGVLA_LEROBOT_VIDEO_DATASET holds a dataset written with `surgvla collect --video av1|h264`;
SURGVLA_LEROBOT_DATASET holds the same episodes in image mode (PNG), the lossless reference.
"""

import os
from pathlib import Path

import numpy as np
import pytest
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

VIDEO_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_VIDEO_DATASET", "")).resolve()
IMAGE_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_DATASET", "")).resolve()
RGB = "observation.images.endoscope"


@pytest.fixture(scope="module")
def video():
    return LeRobotDataset("surgvla/interop-video", root=VIDEO_ROOT, video_backend="pyav", depth_output_unit="m")


@pytest.fixture(scope="module")
def images():
    return LeRobotDataset("surgvla/interop", root=IMAGE_ROOT, depth_output_unit="m")


def test_video_metadata(video):
    assert video.meta.info.codebase_version == "v3.0"
    assert video.features[RGB]["info"]["video.codec"] in ("av1", "h264")
    assert video.features[RGB]["info"]["video.pix_fmt"] == "yuv420p"
    assert RGB in video.meta.video_keys
    assert video.features[RGB]["dtype"] == "video"
    assert video.meta.info.video_path is not None


def test_every_video_frame_decodes_close_to_the_lossless_frame(video, images):
    assert len(video) == len(images)
    worst_psnr = float("inf")
    for i in range(len(video)):
        item = video[i]
        reference = images[i]
        assert item["task"] == reference["task"]
        assert item["episode_index"] == reference["episode_index"]
        assert abs(item["timestamp"].item() - item["frame_index"].item() / video.fps) < 1e-6
        rgb = item[RGB]
        assert rgb.shape == (3, 224, 224) and rgb.dtype == torch.float32
        error = (rgb - reference[RGB]).double()
        mse = float((error**2).mean())
        psnr = 10 * np.log10(1.0 / max(mse, 1e-12))
        worst_psnr = min(worst_psnr, psnr)
        assert psnr > 32.0, f"frame {i}: PSNR {psnr:.1f} dB"
        # Everything else is stored losslessly in the parquet, as in image mode.
        for key in ["observation.state", "action", "observation.images.depth"]:
            assert torch.equal(item[key], reference[key]), (i, key)
    print(f"worst PSNR {worst_psnr:.1f} dB")


def test_episode_video_spans_are_contiguous(video):
    episodes = video.meta.episodes
    previous_end = None
    for e in range(video.num_episodes):
        start = episodes[e][f"videos/{RGB}/from_timestamp"]
        end = episodes[e][f"videos/{RGB}/to_timestamp"]
        length = episodes[e]["length"]
        assert abs((end - start) - length / video.fps) < 1e-9
        if previous_end is not None and episodes[e][f"videos/{RGB}/file_index"] == episodes[e - 1][f"videos/{RGB}/file_index"]:
            assert abs(start - previous_end) < 1e-9
        previous_end = end
