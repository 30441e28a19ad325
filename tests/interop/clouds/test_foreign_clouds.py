"""Another tool's dataset in the formats built around one camera, read by the real clients:
tests/interop/rlds/test_oxe_specs.py builds the held-out maniskill spec with tensorflow_datasets
(uint16 depth in 1/1024 m) and converts it with `--camera observation.images.image --depth
observation.images.depth --depth-unit-m 0.0009765625 --intrinsics 128,128,128,128 --crop ...`
into SURGVLA_ROLES_OUT/{zarr,ply,pcd}, beside expected.npz (the values tfds decoded).

What must hold: zarr 3 reads the store with DP3's `state` and `action` and the other vectors
under their keys, the camera's pixels as tfds decoded them, the episode ends; every point of
every cloud (zarr, plyfile, Open3D) is a pixel of the depth image back-projected with the given
intrinsics, at the depth tfds decoded times the unit, in that pixel's colour.
"""

import json
import os
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import zarr
from plyfile import PlyData

ROOT = Path(os.environ.get("SURGVLA_ROLES_OUT", "")).resolve()


@pytest.fixture(scope="module")
def expected():
    if not (ROOT / "expected.npz").is_file():
        pytest.fail("SURGVLA_ROLES_OUT holds no expected.npz: run tests/interop/rlds/test_oxe_specs.py with it first")
    return dict(np.load(ROOT / "expected.npz"))


def intrinsics():
    return json.loads((ROOT / "expected.json").read_text())["intrinsics"]


def assert_points_are_pixels(xyz, rgb, depth_m, image):
    """Each point (x, y, z): its pixel (u, v) from the pinhole model of the OpenCV intrinsics
    given (pixel centres at integers), whose depth is z and whose colour is the point's."""
    fx, fy, cx, cy = intrinsics()
    assert len(xyz) > 0
    u = np.rint(xyz[:, 0] * fx / xyz[:, 2] + cx).astype(int)
    v = np.rint(xyz[:, 1] * fy / xyz[:, 2] + cy).astype(int)
    np.testing.assert_allclose(xyz[:, 2], depth_m[v, u], rtol=1e-6)
    np.testing.assert_allclose(xyz[:, 0], (u - cx) * xyz[:, 2] / fx, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(rgb, image[v, u])


def test_zarr3_reads_the_vectors_pixels_and_episodes(expected):
    store = zarr.open_group(str(ROOT / "zarr"), mode="r", zarr_format=2)
    np.testing.assert_array_equal(store["meta/episode_ends"][:], expected["episode_ends"])
    np.testing.assert_array_equal(store["data/action"][:], expected["action"])
    np.testing.assert_array_equal(store["data/state"][:], expected["state"])
    np.testing.assert_array_equal(store["data/observation.base_pose"][:], expected["base_pose"])
    # The wrist camera has no place in the store (named on stderr), nor has the instruction.
    assert "observation.images.wrist_image" not in store["data"]
    clouds = store["data/point_cloud"][:]
    assert clouds.shape[:1] == (len(expected["action"]),) and clouds.shape[2] == 6
    attributes = store.attrs.asdict()["surgvla"]
    assert "generator" not in attributes and attributes["camera"]["fx"] == intrinsics()[0]
    assert attributes["camera"]["cx"] == intrinsics()[2] + 0.5, "surgvla's pixel-centre convention"
    for t, cloud in enumerate(clouds):
        real = cloud[np.any(cloud[:, :3] != 0, axis=1)]
        assert_points_are_pixels(real[:, :3], real[:, 3:6].astype(np.uint8), expected["depth_m"][t], expected["image"][t])


def test_plyfile_and_open3d_read_clouds_of_the_named_depth(expected):
    episodes = [json.loads(line) for line in (ROOT / "ply/episodes.jsonl").read_text().splitlines()]
    # No provenance surgvla does not know: no seed, task id or success.
    assert all(set(e) == {"episode_index", "frames", "instruction", "fields"} for e in episodes), episodes
    ids = sorted(e["fields"]["episode_metadata/episode_id"] for e in episodes)
    assert ids == ["episode 0", "episode 1"], episodes
    t = 0
    for episode in episodes:
        for frame in range(episode["frames"]):
            name = f"episode_{episode['episode_index']:06d}/frame_{frame:06d}"
            vertex = PlyData.read(str(ROOT / "ply" / f"{name}.ply"))["vertex"]
            xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
            rgb = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)
            assert_points_are_pixels(xyz, rgb, expected["depth_m"][t], expected["image"][t])
            cloud = o3d.io.read_point_cloud(str(ROOT / "pcd" / f"{name}.pcd"))
            np.testing.assert_allclose(np.asarray(cloud.points), xyz, atol=1e-7)
            t += 1
    assert t == len(expected["action"])


def spec_folders():
    return sorted((ROOT / "specs").iterdir()) if (ROOT / "specs").is_dir() else []


def test_zarr3_reads_every_oxe_spec_with_its_camera():
    """tests/interop/rlds/test_oxe_specs.py converts every Open X-Embodiment spec it builds to
    zarr with --camera: the action (DP3's `data/action`) and the camera's pixels (`data/img`,
    no depth so no clouds) are what tfds read."""
    folders = spec_folders()
    assert len(folders) >= 9, folders
    for folder in folders:
        expected = np.load(folder / "expected.npz")
        store = zarr.open_group(str(folder / "zarr"), mode="r", zarr_format=2)
        action = store["data/action"][:]
        assert action.dtype == expected["action"].dtype, folder.name  # float64 stays float64
        np.testing.assert_array_equal(action, expected["action"], err_msg=folder.name)
        if "image" in expected:  # stored images (lerobot's video is decoded, lossy)
            np.testing.assert_array_equal(store["data/img"][:], expected["image"], err_msg=folder.name)
        assert "point_cloud" not in store["data"], folder.name  # no --depth given
