"""Another tool's dataset as MCAP, read by the real mcap reader (CRCs validated) with
mcap-protobuf-support: tests/interop/rlds/test_oxe_specs.py builds the held-out maniskill spec
with tensorflow_datasets and converts it with `--camera observation.images.image --depth
observation.images.depth --depth-unit-m 0.0009765625 --intrinsics ... --crop ...` into
SURGVLA_ROLES_OUT/mcap, beside expected.json (values tfds read).

What must hold: the camera on /endoscope/rgb, the depth in metres on /endoscope/depth (the
values tfds decoded times the unit, bit for bit), the intrinsics on /endoscope/camera_info,
clouds on /endoscope/points; every other feature on a channel of its own named by its key
(`action` on /action with the values tfds read, the wrist camera's PNG bytes as stored);
no surgvla state or action channels and no provenance surgvla does not know.
"""

import hashlib
import json
import os
from pathlib import Path

import pytest
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

ROOT = Path(os.environ.get("SURGVLA_ROLES_OUT", "")).resolve()
T0_NS = 1_704_067_200_000_000_000


class JsonDecoderFactory(McapDecoderFactory):
    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json" and schema is not None and schema.encoding == "jsonschema":
            return lambda data: json.loads(data)
        return None


@pytest.fixture(scope="module")
def expected():
    if not (ROOT / "expected.json").is_file():
        pytest.fail("SURGVLA_ROLES_OUT holds no expected.json: run tests/interop/rlds/test_oxe_specs.py with it first")
    return json.loads((ROOT / "expected.json").read_text())


def test_the_named_camera_depth_and_every_other_feature_are_on_channels(expected):
    lines = [json.loads(line) for line in (ROOT / "mcap/episodes.jsonl").read_text().splitlines()]
    assert [e["frames"] for e in lines] == expected["lengths"]
    t = actions = 0
    for entry in lines:
        with open(ROOT / "mcap" / entry["file"], "rb") as f:
            reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory(), JsonDecoderFactory()])
            topics = {c.topic for c in reader.get_summary().channels.values()}
            assert {"/endoscope/rgb", "/endoscope/depth", "/endoscope/camera_info", "/endoscope/points", "/action",
                    "/observation/state", "/observation/images/wrist_image", "/language_embedding"} <= topics, topics
            assert not topics & {"/robot/state", "/robot/action"}, topics
            metadata = {m.name: m.metadata for m in reader.iter_metadata()}["episode"]
            assert set(metadata) == {"episode_index", "instruction"}, metadata
            first = t
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                topic = channel.topic
                # The step's index in the dataset: t0 + step / 10 Hz.
                t = first + (message.log_time - T0_NS) // 100_000_000
                if topic == "/episode/info":
                    assert "seed" not in decoded and "task_id" not in decoded, decoded
                    assert decoded["instruction"] == expected["instructions"][first]
                    assert set(decoded["fields"]) == {"episode_metadata/episode_id", "episode_metadata/file_path"}
                elif topic == "/endoscope/rgb":
                    assert decoded.format == "png" and decoded.data[:8] == b"\x89PNG\r\n\x1a\n"
                elif topic == "/endoscope/depth":
                    assert decoded.encoding == "32FC1" and decoded.width == decoded.height == 256
                    assert hashlib.sha256(decoded.data).hexdigest() == expected["depth_m_sha256"][t]
                elif topic == "/endoscope/camera_info":
                    fx, fy, cx, cy = expected["intrinsics"]
                    assert (decoded.K[0], decoded.K[4], decoded.K[2], decoded.K[5]) == (fx, fy, cx, cy)
                elif topic == "/endoscope/points":
                    assert len(decoded.data) == 16 * 1024
                elif topic == "/observation/images/wrist_image":
                    assert decoded.format == "png"
                    assert hashlib.sha256(decoded.data).hexdigest() == expected["wrist_png_sha256"][t]
                elif topic == "/action":
                    assert decoded["values"] == pytest.approx(expected["action"][t], rel=0, abs=0)
                    actions += 1
            t = first + entry["frames"]
    assert actions == t == sum(expected["lengths"])


def test_every_oxe_spec_has_its_action_on_a_channel():
    """Every Open X-Embodiment spec tests/interop/rlds/test_oxe_specs.py converts to MCAP
    with --camera: /action carries the action tfds read (its JSON numbers are the float32
    values, exactly), the camera is on /endoscope/rgb, one message of each per step."""
    folders = sorted((ROOT / "specs").iterdir()) if (ROOT / "specs").is_dir() else []
    assert len(folders) >= 9, folders
    for folder in folders:
        expected = json.loads((folder / "expected.json").read_text())
        lines = [json.loads(line) for line in (folder / "mcap/episodes.jsonl").read_text().splitlines()]
        assert [e["frames"] for e in lines] == expected["lengths"], folder.name
        actions, frames = [], 0
        for entry in lines:
            with open(folder / "mcap" / entry["file"], "rb") as f:
                reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory(), JsonDecoderFactory()])
                for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=True):
                    if channel.topic == "/action":
                        actions.append(decoded["values"])
                    elif channel.topic == "/endoscope/rgb":
                        frames += 1
        assert actions == expected["action"], folder.name
        assert frames == len(actions), folder.name
