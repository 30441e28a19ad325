"""The DP3 zarr store, read by zarr 2.12 / numcodecs 0.12.1 (what 3D Diffusion Policy uses).

.ci/run writes SURGVLA_ZARR_DATASET with `convert <lerobot> --to zarr --zarr-images
--zarr-mask-channel`. DP3's ReplayBuffer reads `data/*` and `meta/episode_ends` exactly like this.
"""

import os
from pathlib import Path

import numpy as np
import zarr

ROOT = Path(os.environ.get("SURGVLA_ZARR_DATASET", "")).resolve()


def test_the_store_has_dp3s_arrays_and_episode_ends():
    root = zarr.open(str(ROOT), mode="r")
    data, meta = root["data"], root["meta"]
    ends = meta["episode_ends"][:]
    assert ends.dtype == np.int64 and len(ends) >= 1
    assert np.all(np.diff(np.concatenate([[0], ends])) > 0), "cumulative exclusive ends"
    steps = int(ends[-1])
    cloud = data["point_cloud"]
    assert cloud.dtype == np.float32 and cloud.shape[0] == steps and cloud.shape[2] == 7
    assert cloud.chunks[0] == 100
    assert cloud.compressor.codec_id == "zstd"
    for key, shape in [("state", (steps, 7)), ("action", (steps, 7))]:
        assert data[key].shape == shape and data[key].dtype == np.float32
        assert np.all(np.isfinite(data[key][:]))
    assert data["img"].shape == (steps, 224, 224, 3) and data["img"].dtype == np.uint8
    assert data["depth"].shape == (steps, 224, 224) and data["depth"].dtype == np.float32


def test_clouds_are_in_the_crop_box_coloured_and_padded_at_the_end():
    root = zarr.open(str(ROOT), mode="r")
    settings = root.attrs["surgvla"]["point_cloud"]
    low, high = np.array(settings["crop_m"]["min"]), np.array(settings["crop_m"]["max"])
    clouds = root["data/point_cloud"][:]
    for t, cloud in enumerate(clouds):
        real = np.any(cloud[:, :3] != 0, axis=1)
        count = int(real.sum())
        assert count > 0, f"frame {t} has points"
        assert np.all(real[:count]) and not np.any(real[count:]), "padding only at the end"
        xyz = cloud[:count, :3]
        assert np.all(xyz >= low - 1e-5) and np.all(xyz <= high + 1e-5), f"frame {t} inside the crop"
        assert np.all((cloud[:, 3:6] >= 0) & (cloud[:, 3:6] <= 255))
        assert np.all(cloud[:, 6] == np.round(cloud[:, 6])), "mask ids are integers"
    # The depth image reproduces the cloud's scale: metres, in range.
    depth = root["data/depth"][0]
    assert 0 < depth.max() < 1.0
