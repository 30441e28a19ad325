"""`surgvla eval` against a policy server built on openpi-client's own encoding.

What surgvla sends must decode with `openpi_client.msgpack_numpy.unpackb` into the arrays the
issue names (uint8 (224, 224, 3) image, float32 (7,) state, the prompt, and depth / object poses
only when asked), and what such a server answers must be executed: the trial runs to its step
limit with one request per `--replan-steps` actions, and no trial fails for the policy.

SURGVLA_BIN: the surgvla binary.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from openpi_client import websocket_client_policy

HERE = Path(__file__).parent
BIN = os.environ.get("SURGVLA_BIN", "surgvla")


@pytest.fixture
def server(tmp_path, request):
    policy, chunk = getattr(request, "param", ("zeros", 8))
    log = tmp_path / "seen.jsonl"
    process = subprocess.Popen(
        [sys.executable, str(HERE / "trivial_server.py"), "--policy", policy, "--chunk", str(chunk), "--log", str(log)],
        stdout=subprocess.PIPE,
        text=True,
    )
    line = process.stdout.readline()
    assert line.startswith("serving policy on "), line
    yield line.split()[-1], log
    process.terminate()
    process.wait(timeout=10)


def surgvla_eval(url, out, *extra):
    run = subprocess.run(
        [BIN, "eval", "--policy", url, "--out", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    return json.loads((out / "results.json").read_text()), run.stdout


def seen(log):
    return [json.loads(line) for line in log.read_text().splitlines()]


def test_the_test_server_speaks_openpis_protocol(server):
    # openpi's own client talks to it: metadata first, then an action chunk per observation.
    url, log = server
    import numpy as np

    client = websocket_client_policy.WebsocketClientPolicy(url)
    assert client.get_server_metadata() == {"policy": "zeros", "chunk": 8}
    reply = client.infer(
        {
            "observation/image": np.zeros((224, 224, 3), np.uint8),
            "observation/state": np.zeros(7, np.float32),
            "prompt": "pick up the gauze",
        }
    )
    assert reply["actions"].shape == (8, 7)


def test_eval_sends_image_state_and_prompt_and_replans(server, tmp_path):
    url, log = server
    results, stdout = surgvla_eval(url, tmp_path / "eval", "--tasks", "T1-1,T3-1", "--trials", "2", "--replan-steps", "5")
    # The terminal's table: aligned columns (task, name, trials, successes, ...).
    row = next(line.split() for line in stdout.splitlines() if line.startswith("T1-1 "))
    assert row[:4] == ["T1-1", "gauze_pick", "2", "0"], stdout
    rows = {row["task_id"]: row for row in results["tasks"]}
    assert rows["T1-1"]["trials"] == 2 and rows["T3-1"]["trials"] == 2
    assert all(row["policy_errors"] == 0 for row in rows.values()), results["trials"]
    steps = [t["steps"] for t in results["trials"]]
    assert steps == [100, 100, 150, 150], steps
    observations = seen(log)
    # 5 actions of each 8-action chunk are executed: one request per 5 steps.
    assert len(observations) == sum(s // 5 for s in steps)
    first = observations[0]
    assert set(first) == {"observation/image", "observation/state", "prompt"}
    assert first["observation/image"][:2] == ["uint8", [224, 224, 3]]
    assert first["observation/state"][:2] == ["float32", [7]]
    assert first["prompt"] == "pick up the gauze"
    assert observations[-1]["prompt"] == "pick up the gauze and place it on the block"
    # The image is a real rendering (not blank) and the state moves only as told (zeros: it stays).
    assert 20 < first["observation/image"][2] < 235
    assert results["policy_metadata"] == {"policy": "zeros", "chunk": 8}
    assert results["options"]["sent"]["observation/depth"] is False
    # The failed trials' recordings exist (three per task by default; two trials each here).
    recordings = [t["recording"] for t in results["trials"] if "recording" in t]
    assert len(recordings) == 4
    assert all((tmp_path / "eval" / r).is_file() for r in recordings)


@pytest.mark.parametrize("server", [("square", 4)], indirect=True)
def test_privileged_observations_only_when_asked_and_whole_chunks_by_default(server, tmp_path):
    url, log = server
    results, _ = surgvla_eval(
        url, tmp_path / "eval", "--tasks", "T2-2", "--trials", "1", "--send", "depth,environment_state",
        "--instructions", "paraphrase", "--record-failures", "0",
    )
    observations = seen(log)
    assert len(observations) == 100 // 4
    first = observations[0]
    assert first["observation/depth"][:2] == ["float32", [224, 224]]
    assert first["observation/environment_state"][:2] == ["float32", [28]]
    # Depth is metres from the endoscope: the tray is some 10-30 cm away.
    assert 0.05 < first["observation/depth"][2] < 0.5
    assert first["prompt"] != "pick up the needle"
    assert results["trials"][0]["instruction"] == first["prompt"]
    assert results["options"]["sent"]["observation/environment_state"] is True
