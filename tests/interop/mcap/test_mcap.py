"""surgvla's MCAP recordings, read by the real mcap reader (CRCs validated, indexed reading) with
mcap-protobuf-support decoding every protobuf message from the schemas in the file, compared with
Foxglove's own message types (foxglove-schemas-protobuf).

.ci/run writes SURGVLA_MCAP_DATASET with `convert <lerobot> --to mcap`.
"""

import json
import os
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

ROOT = Path(os.environ.get("SURGVLA_MCAP_DATASET", "")).resolve()
T0_NS = 1_704_067_200_000_000_000
PROTOBUF = {
    "/endoscope/rgb": CompressedImage,
    "/endoscope/depth": RawImage,
    "/endoscope/camera_info": CameraCalibration,
    "/endoscope/points": PointCloud,
    "/tf": FrameTransforms,
}


class JsonDecoderFactory(McapDecoderFactory):
    """JSON channels with a JSON schema, as Foxglove reads them."""

    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json" and schema is not None and schema.encoding == "jsonschema":
            assert json.loads(schema.data)["type"] == "object"
            return lambda data: json.loads(data)
        return None


def episodes():
    return [json.loads(line) for line in (ROOT / "episodes.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("episode", range(2))
def test_every_message_decodes_with_crcs_checked(episode):
    entry = episodes()[episode]
    frames = entry["frames"]
    with open(ROOT / entry["file"], "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory(), JsonDecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes, "indexed, chunked"
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        schemas = {s.name for s in summary.schemas.values()}
        assert {f"foxglove.{t.__name__}" for t in PROTOBUF.values()} <= schemas
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert metadata["episode"]["task_id"] == entry["task_id"]
        assert metadata["episode"]["seed"] == str(entry["seed"])
        counts, times = {}, {}
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            assert message.log_time == message.publish_time
            times.setdefault(message.log_time, set()).add(topic)
            if topic in PROTOBUF:
                assert schema.name == f"foxglove.{PROTOBUF[topic].__name__}"
                # The same bytes parse as Foxglove's own type, to the same message.
                ours = PROTOBUF[topic]()
                ours.ParseFromString(message.data)
                assert ours.SerializeToString() == decoded.SerializeToString()
            if topic == "/endoscope/rgb":
                assert decoded.format == "png" and decoded.data[:8] == b"\x89PNG\r\n\x1a\n"
                assert decoded.frame_id == "endoscope_optical"
            elif topic == "/endoscope/depth":
                assert decoded.encoding == "32FC1" and decoded.width == decoded.height == 224
                assert len(decoded.data) == 224 * 224 * 4 and decoded.step == 224 * 4
            elif topic == "/endoscope/points":
                assert decoded.point_stride == 16 and decoded.frame_id == "world"
                assert [f.name for f in decoded.fields] == ["x", "y", "z", "red", "green", "blue", "alpha"]
                assert len(decoded.data) == 16 * 1024
                # The identity pose, stated (rerun's MCAP import requires a pose).
                assert decoded.HasField("pose")
                p, q = decoded.pose.position, decoded.pose.orientation
                assert (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == (0, 0, 0, 0, 0, 0, 1)
            elif topic == "/tf":
                children = {t.child_frame_id for t in decoded.transforms}
                assert {"endoscope_optical", "tool_tip", "object_0"} <= children
                assert all(t.parent_frame_id == "world" for t in decoded.transforms)
            elif topic == "/robot/state":
                assert set(decoded) >= {"tip_position_m", "tip_euler_xyz_rad", "jaw_angle_rad"}
            elif topic == "/robot/action":
                assert decoded["gripper_open"] in (0.0, 1.0)
            elif topic == "/episode/info":
                assert decoded["frames"] == frames and decoded["success"] is True
        for topic in list(PROTOBUF) + ["/robot/state", "/robot/action"]:
            assert counts[topic] == frames, topic
        assert counts["/episode/info"] == 1
        # Times: t0 + step / fps, the same for every topic of a step.
        steps = sorted(t for t in times if len(times[t]) > 1)
        assert steps[0] == T0_NS and len(steps) == frames
        assert all(b - a == 200_000_000 for a, b in zip(steps, steps[1:])), "5 Hz"


def test_a_recorded_episode_has_the_scene_and_the_instruments_frames():
    """`surgvla record` (SURGVLA_MCAP_RECORDED): the meshes on /scene are locked to frames that
    /tf provides, so Foxglove's 3D panel shows the scene and the instrument moving."""
    path = Path(os.environ.get("SURGVLA_MCAP_RECORDED", "")).resolve()
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory(), JsonDecoderFactory()])
        scenes, frames, moved, events, successes = [], set(), {}, [], []
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic == "/scene":
                assert schema.name == "foxglove.SceneUpdate"
                scenes.append(decoded)
            elif channel.topic == "/robot/state":
                assert len(decoded["joint_positions"]) == 6
                events += [e for e in (decoded["grasped"], decoded["released"]) if e]
                successes.append(decoded["success_so_far"])
            elif channel.topic == "/tf":
                for t in decoded.transforms:
                    frames.add(t.child_frame_id)
                    moved.setdefault(t.child_frame_id, set()).add(round(t.translation.z, 6))
    assert len(scenes) == 1
    entities = scenes[0].entities
    ids = {e.id for e in entities}
    assert {"instrument_shaft", "gauze", "block"} <= ids, ids
    for entity in entities:
        assert entity.frame_locked and entity.frame_id in frames | {"world"}, entity.frame_id
        (triangles,) = entity.triangles
        assert len(triangles.points) > 0 and len(triangles.indices) % 3 == 0
        assert max(triangles.indices) < len(triangles.points)
    assert {"psm_rcm", "psm_link_1", "psm_link_6", "psm_shaft", "psm_jaw_pivot", "tool_tip"} <= frames
    assert events == ["gauze", "gauze"], "T3-1 grasps the gauze and releases it"
    assert successes[-1] is True and successes[0] is False, "success is reached, not given"
    assert len(moved["psm_shaft"]) > 10, "the instrument moves"
