"""Recordings ingested by `surgvla ingest` read with the real lerobot loader: every frame's
state, action and image are those of the message the synchronisation rule selects, worked out
here on its own from the messages make_bags.py planted; each report names the planted dropout.

Every frame's task (its task_index) is the latest instruction at or before it, as is Open-H's
`instruction.text` where the dataset has it; each episode lists its tasks in the order they
first hold.

Environment: SURGVLA_INGEST_CORPUS (make_bags.py's folder), SURGVLA_INGEST_OUT (a folder of
one dataset per recording, named like it), SURGVLA_INGEST_FPS, SURGVLA_INGEST_VIDEO=1 for
datasets whose cameras are lossy video (`--profile open-h`: H.264), compared within a bound.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

CORPUS = Path(os.environ["SURGVLA_INGEST_CORPUS"])
OUT = Path(os.environ["SURGVLA_INGEST_OUT"])
FPS = int(os.environ.get("SURGVLA_INGEST_FPS", "30"))
TOLERANCE_NS = 1_500_000_000 // FPS
WIDTH, HEIGHT = 32, 24
NAMES = sorted(p.name[: -len(".json")] for p in CORPUS.glob("*.json"))
VIDEO = os.environ.get("SURGVLA_INGEST_VIDEO") == "1"


def topics(expected):
    """The sampled and the event streams of a session."""
    arms, cameras = expected["arms"], expected["cameras"]
    sampled = [t for arm in arms for t in (f"/{arm}/measured_cp", f"/{arm}/jaw/measured_js")]
    sampled += [topic for _, topic, _, _ in cameras]
    # Topics a --map file adds are sampled too.
    sampled += [m["topic"] for m in expected.get("mapped", [])]
    sampled += [topic for _, topic in depths(expected)]
    # The instruction is an event too (the datasets are made without --task).
    events = [t for arm in arms for t in (f"/{arm}/setpoint_cp", f"/{arm}/jaw/setpoint_js")]
    return sampled, events + ["/instruction"]


def pattern(k):
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    r = (k * 9 + (x // 8) * 40) % 256
    g = (k * 5 + (y // 8) * 60) % 256
    b = np.full_like(r, (k * 13) % 256)
    return np.stack([r, g, b], axis=-1).astype(np.uint8)


def depths(expected):
    """The depth cameras ingested: none into the open-h profile's video datasets."""
    return [] if VIDEO else expected.get("depths", [])


def depth_pattern(k):
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    return (300 + k * 7 + x * 100 + y * 1000).astype(np.int64)


def rule(expected):
    """The frames the stated rule makes: episodes of {topic: message} per frame."""
    streams = expected["streams"]
    SAMPLED, EVENTS = topics(expected)
    start = max(min(m["stamp"] for m in streams[t]) for t in SAMPLED)
    end = min(max(m["stamp"] for m in streams[t]) for t in SAMPLED)
    episodes, current, k = [], [], 0
    while True:
        time = start + k * 1_000_000_000 // FPS
        if time > end:
            break
        k += 1
        frame, written = {}, True
        for topic in SAMPLED + EVENTS:
            # The greatest stamp at or before the frame; equal stamps: the later message.
            best = None
            for message in streams[topic]:
                if message["stamp"] <= time and (best is None or message["stamp"] >= best["stamp"]):
                    best = message
            if best is None or (topic in SAMPLED and time - best["stamp"] > TOLERANCE_NS):
                written = False
                break
            frame[topic] = best
        if written:
            current.append(frame)
        elif current:
            episodes.append(current)
            current = []
    if current:
        episodes.append(current)
    return episodes


@pytest.mark.parametrize("name", NAMES)
def test_every_frame_is_the_rules_message(name):
    expected = json.loads((CORPUS / f"{name}.json").read_text())
    episodes = rule(expected)
    arms, cameras = expected["arms"], expected["cameras"]
    dataset = LeRobotDataset(repo_id=f"local/{name}", root=OUT / name)
    assert dataset.meta.total_episodes == len(episodes)
    assert dataset.num_frames == sum(len(e) for e in episodes)
    names = dataset.meta.features["observation.state"]["names"]
    assert names == [f"{arm}.{v}" for arm in arms for v in ("x", "y", "z", "qx", "qy", "qz", "qw", "jaw")]
    # The features' own facts: each camera's topic and intrinsics, each pose's frame.
    for camera, topic, _, _ in cameras:
        info = dataset.meta.features[f"observation.images.{camera}"]["info"]
        want = expected["camera_info"][camera]
        assert info["camera.topic"] == topic
        assert info["camera.frame_id"] == want["frame_id"] and info["camera.distortion_model"] == "plumb_bob"
        np.testing.assert_allclose(info["camera.k"], want["k"])
        np.testing.assert_allclose(info["camera.d"], want["d"])
    for name, topic in depths(expected):
        info = dataset.meta.features[f"observation.images.{name}"]["info"]
        assert info["is_depth_map"] is True and info["depth_unit"] == "mm" and info["camera.topic"] == topic
    for key in ("observation.state", "action"):
        info = dataset.meta.features[key]["info"]
        assert all(info[f"{arm}.frame_id"] == "world" for arm in arms), info
    text = "instruction.text" in dataset.meta.features
    assert text == (VIDEO or "--instruction-text" in expected["ingest_args"])
    index = 0
    for e, frames in enumerate(episodes):
        tasks = list(dict.fromkeys(frame["/instruction"]["value"] for frame in frames))
        assert list(dataset.meta.episodes[e]["tasks"]) == tasks, f"episode {e}"
        for f, frame in enumerate(frames):
            item = dataset[index]
            index += 1
            assert int(item["episode_index"]) == e and int(item["frame_index"]) == f
            assert abs(float(item["timestamp"]) - f / FPS) < 1e-4
            state = [v for arm in arms for v in frame[f"/{arm}/measured_cp"]["value"] + [frame[f"/{arm}/jaw/measured_js"]["value"]]]
            action = [v for arm in arms for v in frame[f"/{arm}/setpoint_cp"]["value"] + [frame[f"/{arm}/jaw/setpoint_js"]["value"]]]
            np.testing.assert_allclose(item["observation.state"].numpy(), np.float32(state), rtol=0, atol=0)
            np.testing.assert_allclose(item["action"].numpy(), np.float32(action), rtol=0, atol=0)
            for camera, topic, encoding, _ in cameras:
                image = (item[f"observation.images.{camera}"].numpy().transpose(1, 2, 0) * 255).round().astype(np.int32)
                want = pattern(frame[topic]["value"]).astype(np.int32)
                if encoding == "mono8":
                    want = np.repeat(want[:, :, :1], 3, axis=2)
                if VIDEO:
                    # H.264 of sharp 8-pixel blocks at 32 x 24: near, not equal.
                    assert np.abs(image - want).mean() < 12, f"{camera}: episode {e} frame {f}"
                elif encoding == "jpeg":
                    assert np.abs(image - want).mean() < 6, f"{camera}: episode {e} frame {f}"
                else:
                    assert (image == want).all(), f"{camera}: episode {e} frame {f}"
            assert item["task"] == frame["/instruction"]["value"], f"episode {e} frame {f}"
            if text:
                assert item["instruction.text"] == frame["/instruction"]["value"]
            for name, topic in depths(expected):
                # A 16-bit PNG of millimetres, exact (the loader keeps the integers).
                depth = item[f"observation.images.{name}"].numpy().astype(np.int64).reshape(HEIGHT, WIDTH)
                assert (depth == depth_pattern(frame[topic]["value"])).all(), f"{name}: episode {e} frame {f}"
            for m in expected.get("mapped", []):
                np.testing.assert_allclose(item[m["name"]].numpy(), np.float32(frame[m["topic"]]["value"]), rtol=0, atol=0)


@pytest.mark.parametrize("name", NAMES)
def test_the_report_names_the_dropout(name):
    reports = list((OUT / name / "meta" / "sync").glob("*.json"))
    assert len(reports) == 1
    report = json.loads(reports[0].read_text())
    camera = next(s for s in report["streams"] if s["topic"] == "/camera/left/image")
    start = 1_700_000_000_000_000_000
    assert any(g["start"] < start + 1_200_000_000 and g["end"] >= start + 1_600_000_000 for g in camera["gaps"]), camera["gaps"]
    assert camera["out_of_order"] == 1
    assert report["episodes"] == [len(e) for e in rule(json.loads((CORPUS / f"{name}.json").read_text()))]
    card = (OUT / name / "README.md").read_text()
    assert "Synchronisation" in card and "/camera/left/image" in card
