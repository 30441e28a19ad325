"""`surgvla validate` (full and `--quick`) and `info` on what lerobot 0.6.1's own
`lerobot-edit-dataset` writes from surgvla datasets (delete_episodes, split, remove_feature,
modify_tasks, convert_image_to_video, merge): every operation's output is valid, and the
three agree with each other and with the dataset's own totals (the quick pass once counted the
episodes of a row group lerobot writes several into as one).

SURGVLA_BIN is the surgvla binary; SURGVLA_LEROBOT_DATASET (image mode) and
SURGVLA_LEROBOT_VIDEO_DATASET (video mode) are surgvla datasets of six episodes.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
EDIT = str(Path(sys.executable).parent / "lerobot-edit-dataset")

OPERATIONS = [
    ("images", "delete_episodes", ["--operation.episode_indices", "[0, 2, 3]"]),
    ("videos", "delete_episodes", ["--operation.episode_indices", "[1, 4]"]),
    ("images", "split", ["--operation.splits", '{"train": [0, 1, 2, 3], "val": [4, 5]}']),
    ("videos", "split", ["--operation.splits", '{"train": 0.5, "val": 0.5}']),
    ("images", "remove_feature", ["--operation.feature_names", '["observation.images.depth"]']),
    ("images", "modify_tasks", ["--operation.new_task", "pick it up"]),
    ("images", "convert_image_to_video", []),
    ("videos", "merge", []),
]


def source(kind: str) -> Path:
    variable = "SURGVLA_LEROBOT_DATASET" if kind == "images" else "SURGVLA_LEROBOT_VIDEO_DATASET"
    path = os.environ.get(variable)
    if not path:
        pytest.skip(f"{variable} is not set")
    return Path(path)


def surgvla_json(*args: str) -> tuple[int, dict]:
    run = subprocess.run([BIN, *args, "--json"], capture_output=True, text=True)
    return run.returncode, json.loads(run.stdout)


@pytest.mark.parametrize("kind,operation,args", OPERATIONS, ids=[f"{k}-{o}" for k, o, _ in OPERATIONS])
def test_validate_quick_and_info_agree_on_what_lerobots_edit_tool_writes(tmp_path, kind, operation, args):
    original = source(kind)
    # The tool may write beside its input: it works on a copy.
    copy = tmp_path / "source"
    shutil.copytree(original, copy)
    out = tmp_path / "edited"
    command = [EDIT, "--repo_id", "local/source", "--root", str(copy), "--new_repo_id", "local/edited",
               "--new_root", str(out), "--operation.type", operation, *args]
    if operation == "convert_image_to_video":
        command += ["--operation.output_dir", str(out)]
    if operation == "merge":
        # The dataset with a second copy of itself.
        second = tmp_path / "second"
        shutil.copytree(original, second)
        command = [EDIT, "--new_repo_id", "local/edited", "--new_root", str(out), "--operation.type", "merge",
                   "--operation.repo_ids", '["local/source", "local/second"]',
                   "--operation.roots", json.dumps([str(copy), str(second)])]
    run = subprocess.run(command, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-3000:]
    # What it wrote; an operation that edits in place (modify_tasks) leaves the copy edited.
    datasets = sorted({p.parent.parent for p in tmp_path.rglob("meta/info.json")} - {copy, tmp_path / "second"}) or [copy]
    for dataset in datasets:
        info = json.loads((dataset / "meta/info.json").read_text())
        totals = (info["total_episodes"], info["total_frames"])
        full_code, full = surgvla_json("validate", str(dataset))
        quick_code, quick = surgvla_json("validate", "--quick", str(dataset))
        info_code, summary = surgvla_json("info", str(dataset))
        where = f"{operation} -> {dataset.name}"
        assert (full_code, quick_code, info_code) == (0, 0, 0), (where, full["errors"], quick["errors"])
        assert (full["episodes"], full["frames"]) == totals, where
        assert (quick["episodes"], quick["frames"]) == totals, where
        assert (summary["episodes"], summary["frames"]) == totals, where
