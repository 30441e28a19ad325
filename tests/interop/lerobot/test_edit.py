"""`surgvla edit` read by lerobot 0.6.1: every edited dataset loads with the expected episodes,
frames and tasks; `edit --drop` holds what `lerobot-edit-dataset delete_episodes` holds
(episodes, frames, actions, states, tasks), its video frames the input's exactly (decoded
frames and the MP4 sample bytes), its quantiles exact where lerobot's are averaged; a dataset
lerobot wrote keeps its metadata (info.json's features and unknown keys, files beside it).

SURGVLA_BIN is the surgvla binary; SURGVLA_LEROBOT_DATASET (image mode),
SURGVLA_LEROBOT_VIDEO_DATASET (AV1 video) and SURGVLA_LEROBOT_V21_DATASET (v2.1) are surgvla
datasets of six episodes.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402
from test_validate_foreign import make  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
EDIT = str(Path(sys.executable).parent / "lerobot-edit-dataset")
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}


def dataset(variable: str) -> Path:
    path = os.environ.get(variable)
    if not path:
        pytest.skip(f"{variable} is not set")
    return Path(path)


@pytest.fixture(scope="module")
def lerobot_videos(tmp_path_factory):
    return make(tmp_path_factory.mktemp("edit-foreign") / "videos", video=True)


def edit(source: Path, out: Path, *args: str) -> str:
    done = subprocess.run([BIN, "edit", str(source), "--out", str(out), *args], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


def load(root: Path) -> LeRobotDataset:
    """The dataset as lerobot 0.6.1 reads it: v2.1 through its own converter (on a copy)."""
    if '"v2.1"' in (root / "meta/info.json").read_text():
        copy = root.parent / f"{root.name}-as-v30"
        if not copy.exists():
            from lerobot.scripts.convert_dataset_v21_to_v30 import convert_dataset

            shutil.copytree(root, copy)
            convert_dataset("local/edited", root=copy, push_to_hub=False)
        root = copy
    return LeRobotDataset("local/edited", root=root, video_backend="pyav")


def camera_of(ds: LeRobotDataset) -> str:
    return next(k for k, f in ds.features.items() if f["dtype"] in ("video", "image") and "depth" not in k)


def samples(ds: LeRobotDataset, key: str, episode: int) -> list[bytes]:
    """The MP4 sample bytes of one episode's span, in decode order."""
    row = ds.meta.episodes[episode]
    path = ds.root / ds.meta.video_path.format(
        video_key=key, chunk_index=row[f"videos/{key}/chunk_index"], file_index=row[f"videos/{key}/file_index"])
    start, end = row[f"videos/{key}/from_timestamp"], row[f"videos/{key}/to_timestamp"]
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return [bytes(p) for p in container.demux(stream)
                if p.pts is not None and start - 1e-4 <= float(p.pts * p.time_base) < end - 1e-4]


def episode_frames(ds: LeRobotDataset, episode: int) -> range:
    row = ds.meta.episodes[episode]
    return range(row["dataset_from_index"], row["dataset_to_index"])


@pytest.mark.parametrize("which", ["surgvla", "lerobot"])
def test_drop_holds_what_lerobots_delete_episodes_holds(which, lerobot_videos, tmp_path):
    source = dataset("SURGVLA_LEROBOT_VIDEO_DATASET") if which == "surgvla" else lerobot_videos
    dropped = [1]
    ours, theirs = tmp_path / "ours", tmp_path / "theirs"
    edit(source, ours, "--drop", ",".join(map(str, dropped)), "--verify")
    copy = tmp_path / "copy"
    shutil.copytree(source, copy)
    done = subprocess.run([EDIT, "--repo_id", "local/source", "--root", str(copy), "--new_repo_id", "local/theirs",
                           "--new_root", str(theirs), "--operation.type", "delete_episodes",
                           "--operation.episode_indices", json.dumps(dropped)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    original, a, b = load(source), load(ours), load(theirs)
    kept = [e for e in range(original.num_episodes) if e not in dropped]
    assert a.num_episodes == b.num_episodes == len(kept)
    assert len(a) == len(b) == sum(len(episode_frames(original, e)) for e in kept)
    camera = camera_of(original)
    originals = [i for e in kept for i in episode_frames(original, e)]
    for i, j in enumerate(originals):
        x, y, z = a[i], b[i], original[j]
        assert x["task"] == y["task"] == z["task"], i
        for key in ["action", "observation.state", "episode_index", "frame_index", "index", "timestamp"]:
            assert torch.equal(x[key], y[key]), (i, key)
        # Copied, not encoded again: exactly the input's decoded frame.
        assert torch.equal(x[camera], z[camera]), i
    for k, e in enumerate(kept):
        assert samples(a, camera, k) == samples(original, camera, e), f"episode {e}: samples differ"
    # Statistics over the kept frames: our quantiles exact (numpy's linear rule).
    actions = np.stack([original[j]["action"].numpy() for j in originals]).astype(np.float64)
    ours_stats = json.loads((ours / "meta/stats.json").read_text())["action"]
    theirs_stats = json.loads((theirs / "meta/stats.json").read_text())["action"]
    worst = 0.0
    for name, q in QUANTILES.items():
        expected = np.quantile(actions, q, axis=0)
        assert np.allclose(ours_stats[name], expected, atol=1e-6, rtol=1e-6), name
        worst = max(worst, float(np.max(np.abs(np.array(theirs_stats[name]) - expected))))
    print(f"{which}: lerobot's quantiles are off by up to {worst:.3g}; ours are exact")


@pytest.mark.parametrize("variable", ["SURGVLA_LEROBOT_DATASET", "SURGVLA_LEROBOT_VIDEO_DATASET", "SURGVLA_LEROBOT_V21_DATASET"])
def test_every_edit_loads_in_lerobot_with_the_expected_content(variable, tmp_path):
    source = tmp_path / "source"
    shutil.copytree(dataset(variable), source)
    original = load(source)
    tasks = [original.meta.episodes[e]["tasks"][0] for e in range(original.num_episodes)]
    first_task = tasks[0]
    cases = {
        "split": (["--split", "train=0.5,val=0.5", "--seed", "1"], None),
        "in-info": (["--split", "train=0.5,val=0.5", "--seed", "1", "--splits-in-info"], None),
        "task": (["--keep", f"task={first_task}"], [e for e, t in enumerate(tasks) if t == first_task]),
        "renamed": (["--drop", "0", "--rename-feature", f"{camera_of(original)}=observation.images.image",
                     "--set-task", "do the task"], list(range(1, original.num_episodes))),
    }
    for name, (args, kept) in cases.items():
        out = tmp_path / name
        edit(source, out, *args)
        roots = [out / "train", out / "val"] if name == "split" else [out]
        total = 0
        for root in roots:
            ds = load(root)
            assert ds.num_episodes == ds.meta.total_episodes and len(ds) == ds.meta.total_frames, (name, root)
            total += ds.num_episodes
            for i in range(len(ds)):
                ds[i]
        if kept is None:
            assert total == original.num_episodes, name
            if name == "in-info":
                splits = json.loads((out / "meta/info.json").read_text())["splits"]
                assert set(splits) == {"train", "val"}, splits
            continue
        ds = load(out)
        assert ds.num_episodes == len(kept), name
        assert len(ds) == sum(len(episode_frames(original, e)) for e in kept), name
        if name == "renamed":
            assert "observation.images.image" in ds.features
            assert {ds[i]["task"] for i in range(len(ds))} == {"do the task"}
            first = ds[0]["observation.images.image"]
            assert torch.equal(first, original[episode_frames(original, 1)[0]][camera_of(original)])
        else:
            assert {ds[i]["task"] for i in range(len(ds))} == {first_task}


def test_a_dataset_lerobot_wrote_keeps_its_metadata(lerobot_videos, tmp_path):
    source = tmp_path / "source"
    shutil.copytree(lerobot_videos, source)
    info = json.loads((source / "meta/info.json").read_text())
    info["contributor"] = {"institution": "a hospital", "arms": ["psm1", "psm2"]}
    (source / "meta/info.json").write_text(json.dumps(info, indent=4))
    (source / "meta/README.md").write_text("# An Open-H contribution\n")
    out = tmp_path / "edited"
    edit(source, out, "--drop", "0")
    edited = json.loads((out / "meta/info.json").read_text())
    for key, value in info.items():
        if key in ("total_episodes", "total_frames", "total_tasks", "splits"):
            continue
        assert edited.get(key) == value, key
    assert edited["total_episodes"] == info["total_episodes"] - 1
    assert (out / "meta/README.md").read_text() == "# An Open-H contribution\n"
    ds = load(out)
    assert ds.meta.robot_type == "aloha" and ds.fps == 50 and ds.num_episodes == info["total_episodes"] - 1
