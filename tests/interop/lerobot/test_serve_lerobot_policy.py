"""examples/serve_lerobot_policy.py: a LeRobot policy trained on a surgvla dataset, served over
openpi's protocol and scored by `surgvla eval`, one command on each side.

The policy is ACT after one lerobot-train step from random initialisation (no backbone weights,
no network): tiny and untrained, so it fails the tasks, but every step of the protocol runs for
real: lerobot's saved pre- and post-processors, `predict_action_chunk`, openpi-client's
msgpack-numpy beside numpy 2 (installed with --no-deps), surgvla's client and its executor.

SURGVLA_LEROBOT_TRAIN_DATASET: a `collect --without depth,environment_state` dataset.
SURGVLA_BIN: the surgvla binary.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

TRAIN_ROOT = Path(os.environ.get("SURGVLA_LEROBOT_TRAIN_DATASET", "")).resolve()
BIN = os.environ.get("SURGVLA_BIN", "surgvla")
EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "serve_lerobot_policy.py"
LEROBOT_TRAIN = Path(sys.executable).parent / "lerobot-train"
OFFLINE = dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1")


def test_a_lerobot_policy_served_by_the_example_is_evaluated(tmp_path):
    assert (TRAIN_ROOT / "meta" / "info.json").is_file(), TRAIN_ROOT
    train = subprocess.run(
        [
            str(LEROBOT_TRAIN),
            "--dataset.repo_id=surgvla/benchmark",
            f"--dataset.root={TRAIN_ROOT}",
            "--policy.type=act",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            "--policy.pretrained_backbone_weights=null",
            "--wandb.enable=false",
            f"--output_dir={tmp_path / 'train'}",
            "--steps=1",
            "--batch_size=2",
            "--num_workers=0",
            "--save_freq=1",
            "--save_checkpoint=true",
        ],
        capture_output=True,
        text=True,
        env=OFFLINE,
        timeout=1800,
    )
    assert train.returncode == 0, (train.stdout + train.stderr)[-4000:]
    model = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    assert (model / "config.json").is_file()

    server = subprocess.Popen(
        [sys.executable, str(EXAMPLE), "--policy-path", str(model), "--port", "0", "--device", "cpu"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=OFFLINE,
    )
    try:
        # lerobot prints its own lines first ("Loading weights from local directory").
        lines = []
        while not (lines and lines[-1].startswith("serving ")) and len(lines) < 50:
            lines.append(server.stdout.readline())
            assert lines[-1], "".join(lines)
        line = lines[-1]
        assert line.startswith("serving act on ws://"), "".join(lines)
        url = line.split()[-1]
        out = tmp_path / "eval"
        run = subprocess.run(
            [BIN, "eval", "--policy", url, "--tasks", "T1-1", "--trials", "2", "--replan-steps", "10", "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert run.returncode == 0, run.stdout + run.stderr
    finally:
        server.terminate()
        server.wait(timeout=30)
    results = json.loads((out / "results.json").read_text())
    assert results["policy_metadata"]["policy_type"] == "act"
    assert results["policy_metadata"]["input_features"] == {
        "observation.images.endoscope": [3, 224, 224],
        "observation.state": [7],
    }
    row = results["tasks"][0]
    assert (row["task_id"], row["trials"], row["policy_errors"]) == ("T1-1", 2, 0), results["trials"]
    # Every trial ran to the step limit on the policy's actions (an untrained ACT does not
    # pick up the gauze).
    assert [t["steps"] for t in results["trials"]] == [100, 100], results["trials"]
    assert all("step limit 100 reached" in t["reason"] for t in results["trials"])
    # The served policy's trials carry their cascade and failure classes, consistently: the
    # stage counts never grow along the chain, every failed trial has one class, and each
    # trial's stage is the furthest the cascade counts it at.
    cascade = list(row["stages"].values())
    assert list(row["stages"]) == ["reached", "grasped", "lifted"]
    assert all(a >= b for a, b in zip(cascade, cascade[1:])), row["stages"]
    assert sum(row["failure_classes"].values()) == row["trials"] - row["successes"]
    for trial in results["trials"]:
        assert trial["failure_class"] in ("never_reached", "reached_no_grasp", "dropped", "timed_out")
        assert trial["stage"] in ("none", "reached", "grasped"), trial
        assert trial["progress"] == {"none": 0.0, "reached": 1 / 3, "grasped": 2 / 3}[trial["stage"]]
        assert trial["path_length_mm"] > 0, "the policy moved the tool"
