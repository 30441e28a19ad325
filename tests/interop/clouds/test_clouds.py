"""surgvla's point clouds, read by the real clients: Open3D and plyfile (PLY, PCD) and zarr 3
(the DP3 store). .ci/run writes, from one LeRobot dataset with the mask:
SURGVLA_PLY_DATASET (`convert --to ply`), SURGVLA_PCD_DATASET (`--to pcd`) and
SURGVLA_ZARR_DATASET (`--to zarr --zarr-images --zarr-mask-channel`). The three must hold the
same clouds.
"""

import json
import os
from pathlib import Path

import numpy as np
import open3d as o3d
import zarr
from plyfile import PlyData

PLY = Path(os.environ.get("SURGVLA_PLY_DATASET", "")).resolve()
PCD = Path(os.environ.get("SURGVLA_PCD_DATASET", "")).resolve()
ZARR = Path(os.environ.get("SURGVLA_ZARR_DATASET", "")).resolve()


def episodes(root):
    return [json.loads(line) for line in (root / "episodes.jsonl").read_text().splitlines()]


def frames(root, extension):
    out = []
    for episode in episodes(root):
        folder = root / f"episode_{episode['episode_index']:06d}"
        files = sorted(folder.glob(f"frame_*.{extension}"))
        assert len(files) == episode["frames"]
        out.extend(files)
    return out


def test_zarr3_reads_the_store_and_its_episode_ends_match_the_files():
    store = zarr.open_group(str(ZARR), mode="r", zarr_format=2)
    ends = store["meta/episode_ends"][:]
    lengths = [e["frames"] for e in episodes(PLY)]
    assert list(np.diff(np.concatenate([[0], ends]))) == lengths
    assert store["data/point_cloud"].shape == (int(ends[-1]), 1024, 7)


def test_plyfile_and_open3d_read_the_same_clouds_as_the_zarr_store():
    clouds = zarr.open_group(str(ZARR), mode="r", zarr_format=2)["data/point_cloud"][:]
    plys = frames(PLY, "ply")
    pcds = frames(PCD, "pcd")
    assert len(plys) == len(pcds) == len(clouds)
    for t, (ply_path, pcd_path) in enumerate(zip(plys, pcds)):
        vertex = PlyData.read(str(ply_path))["vertex"]
        assert vertex.data.dtype.names[:6] == ("x", "y", "z", "red", "green", "blue")
        xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
        rgb = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)
        expected = clouds[t][: len(xyz)]
        np.testing.assert_array_equal(xyz, expected[:, :3])
        np.testing.assert_array_equal(rgb, expected[:, 3:6].astype(np.uint8))
        np.testing.assert_array_equal(vertex["mask"], expected[:, 6].astype(np.uint8))
        assert not np.any(clouds[t][len(xyz):, :3]), "the store pads after the real points"
        for path in (ply_path, pcd_path):
            cloud = o3d.io.read_point_cloud(str(path))
            np.testing.assert_allclose(np.asarray(cloud.points), xyz, atol=1e-7)
            np.testing.assert_allclose(np.asarray(cloud.colors) * 255.0, rgb, atol=1e-3)
