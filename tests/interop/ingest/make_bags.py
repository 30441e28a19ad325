"""Writes the ingest test corpus with the real writers of bags: rosbags (ROS 1 bags, ROS 2 bags
in sqlite3 and mcap storage) and mcap-ros2-support (a single ROS 2 MCAP file).

Usage: make_bags.py OUT_DIR [--bench SECONDS]. Writes OUT_DIR/<name>(.bag|.mcap|/) and
OUT_DIR/<name>.json: every planted message per topic (header stamp, receive time, the values it
carries), from which the check (test_ingest_lerobot.py) works out the synchronisation rule's
frames on its own.

The sessions: ROS 1 bags with lz4 and bz2 chunks, a ROS 2 sqlite3 bag split over two files
without definitions, a ROS 2 sqlite3 bag whose file is zstd-compressed whole, a ROS 2 bag in
mcap storage, a single MCAP file with lz4 chunks, a bimanual ROS 1 bag (PSM1 and PSM2, two
cameras). Each has
a dVRK arm at ~100 Hz with jitter (measured and setpoint poses and jaws), a camera at ~30 Hz
(raw rgb8 / bgr8 / mono8, JPEG and PNG compressed) with a dropout of 0.4 s and two out-of-order
stamps, an unmapped topic and an /instruction topic whose text changes mid-episode.
"""

import json
import random
import sys
from io import BytesIO
from pathlib import Path

import numpy as np
from PIL import Image
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer
from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore

WIDTH, HEIGHT = 32, 24
# The benchmark's images carry sensor noise (PNG then works as on a real endoscope's frames).
NOISE = 0
START_NS = 1_700_000_000_000_000_000
SECONDS = 3.0


def pattern(k):
    """The camera's k-th image: smooth blocks (JPEG keeps them within a few levels)."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    r = (k * 9 + (x // 8) * 40) % 256
    g = (k * 5 + (y // 8) * 60) % 256
    b = np.full_like(r, (k * 13) % 256)
    rgb = np.stack([r, g, b], axis=-1)
    if NOISE:
        rgb = rgb + np.random.default_rng(k).integers(-NOISE, NOISE + 1, rgb.shape)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def plan_session(seed, dropout=True, out_of_order=True):
    """Message times per stream: (stamp ns, receive ns, index) lists."""
    rng = random.Random(seed)
    streams = {}

    def stream(rate, jitter_ms, lag_ms=2.0):
        times, t = [], 0.0
        while t < SECONDS:
            stamp = START_NS + int(t * 1e9) + int(rng.uniform(-jitter_ms, jitter_ms) * 1e6)
            receive = stamp + int((lag_ms + rng.uniform(0, 1)) * 1e6)
            times.append([stamp, receive])
            t += 1.0 / rate
        return times

    streams["arm"] = stream(100, 1.0)
    streams["setpoint"] = stream(50, 1.0)
    camera = stream(30, 3.0, lag_ms=8.0)
    if dropout:
        camera = [m for m in camera if not (1.2e9 <= m[0] - START_NS < 1.6e9)]
    if out_of_order:
        # Two camera messages recorded with their stamps swapped.
        i = len(camera) // 4
        camera[i][0], camera[i + 1][0] = camera[i + 1][0], camera[i][0]
    streams["camera"] = camera
    return streams


def time_msg(ts, ns):
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def header(ts, ros1, ns, frame):
    Header = ts.types["std_msgs/msg/Header"]
    if ros1:
        return Header(seq=0, stamp=time_msg(ts, ns), frame_id=frame)
    return Header(stamp=time_msg(ts, ns), frame_id=frame)


def pose_values(k, offset):
    return [0.01 * k + offset, -0.02 + 0.001 * k, 0.05 + offset, 0.0, 0.0, np.sin(0.01 * k), np.cos(0.01 * k)]


def pose_msg(ts, ros1, ns, values, transform):
    Point = ts.types["geometry_msgs/msg/Point"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    q = Quaternion(x=values[3], y=values[4], z=values[5], w=values[6])
    if transform:
        Vector3 = ts.types["geometry_msgs/msg/Vector3"]
        Transform = ts.types["geometry_msgs/msg/Transform"]
        TransformStamped = ts.types["geometry_msgs/msg/TransformStamped"]
        t = Vector3(x=values[0], y=values[1], z=values[2])
        return TransformStamped(header=header(ts, ros1, ns, "world"), child_frame_id="PSM1", transform=Transform(translation=t, rotation=q))
    Pose = ts.types["geometry_msgs/msg/Pose"]
    PoseStamped = ts.types["geometry_msgs/msg/PoseStamped"]
    p = Point(x=values[0], y=values[1], z=values[2])
    return PoseStamped(header=header(ts, ros1, ns, "world"), pose=Pose(position=p, orientation=q))


def joint_msg(ts, ros1, ns, angle):
    JointState = ts.types["sensor_msgs/msg/JointState"]
    return JointState(header=header(ts, ros1, ns, ""), name=["jaw"], position=np.array([angle]), velocity=np.array([], dtype=np.float64), effort=np.array([], dtype=np.float64))


def depth_pattern(k):
    """A depth camera's k-th image, millimetres."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    return (300 + k * 7 + x * 100 + y * 1000).astype(np.uint16)


def depth_msg(ts, ros1, ns, k):
    Img = ts.types["sensor_msgs/msg/Image"]
    data = np.frombuffer(depth_pattern(k).astype("<u2").tobytes(), dtype=np.uint8)
    return Img(header=header(ts, ros1, ns, "depth"), height=HEIGHT, width=WIDTH, encoding="16UC1", is_bigendian=0, step=WIDTH * 2, data=data)


def image_msg(ts, ros1, ns, k, encoding):
    rgb = pattern(k)
    if encoding in ("jpeg", "png"):
        buffer = BytesIO()
        Image.fromarray(rgb).save(buffer, format=encoding.upper(), quality=95)
        CompressedImage = ts.types["sensor_msgs/msg/CompressedImage"]
        fmt = "rgb8; jpeg compressed bgr8" if encoding == "jpeg" else "png"
        return CompressedImage(header=header(ts, ros1, ns, "camera"), format=fmt, data=np.frombuffer(buffer.getvalue(), dtype=np.uint8))
    if encoding == "bgr8":
        pixels, step = rgb[:, :, ::-1], WIDTH * 3
    elif encoding == "mono8":
        pixels, step = rgb[:, :, 0], WIDTH
    else:
        pixels, step = rgb, WIDTH * 3
    Img = ts.types["sensor_msgs/msg/Image"]
    return Img(header=header(ts, ros1, ns, "camera"), height=HEIGHT, width=WIDTH, encoding=encoding, is_bigendian=0, step=step, data=np.ascontiguousarray(pixels).reshape(-1))


def session_messages(ts, ros1, seed, encoding, transform=False, bimanual=False, mapped=False, **kwargs):
    """Every message of a session, in receive order: (topic, type, receive ns, msg) and the
    expected record, with the arguments `surgvla ingest` takes for it. A bimanual session has
    PSM2 too (its values offset by 1) and a second camera (mono8, its pattern 100 frames on)."""
    streams = plan_session(seed, **kwargs)
    arms = ["PSM1", "PSM2"] if bimanual else ["PSM1"]
    cameras = [["left", "/camera/left/image", encoding, 0]]
    if bimanual:
        cameras.append(["right", "/camera/right/image", "mono8", 100])
    out = []
    expected = {"arms": arms, "cameras": cameras, "streams": {}, "ingest_args": []}
    for arm in arms if bimanual else []:
        expected["ingest_args"] += ["--arm", arm]
    for name, topic, _, _ in cameras:
        expected["ingest_args"] += ["--camera", f"{name}={topic}"]

    def add(topic, msgtype, times, make, value):
        expected["streams"][topic] = []
        for k, (stamp, receive) in enumerate(times):
            out.append((receive, topic, msgtype, make(k, stamp)))
            expected["streams"][topic].append({"stamp": stamp, "receive": receive, "value": value(k)})

    pose_type = "geometry_msgs/msg/TransformStamped" if transform else "geometry_msgs/msg/PoseStamped"
    for a, arm in enumerate(arms):
        add(f"/{arm}/measured_cp", pose_type, streams["arm"], lambda k, s, a=a: pose_msg(ts, ros1, s, pose_values(k, a), transform), lambda k, a=a: pose_values(k, a))
        add(f"/{arm}/jaw/measured_js", "sensor_msgs/msg/JointState", streams["arm"], lambda k, s, a=a: joint_msg(ts, ros1, s, 0.3 + 0.001 * k + a), lambda k, a=a: 0.3 + 0.001 * k + a)
        add(f"/{arm}/setpoint_cp", pose_type, streams["setpoint"], lambda k, s, a=a: pose_msg(ts, ros1, s, pose_values(k, 0.5 + a), transform), lambda k, a=a: pose_values(k, 0.5 + a))
        add(f"/{arm}/jaw/setpoint_js", "sensor_msgs/msg/JointState", streams["setpoint"], lambda k, s, a=a: joint_msg(ts, ros1, s, 0.7 - 0.002 * k + a), lambda k, a=a: 0.7 - 0.002 * k + a)
    for _, topic, camera_encoding, shift in cameras:
        msgtype = "sensor_msgs/msg/CompressedImage" if camera_encoding in ("jpeg", "png") else "sensor_msgs/msg/Image"
        add(topic, msgtype, streams["camera"], lambda k, s, e=camera_encoding, d=shift: image_msg(ts, ros1, s, k + d, e), lambda k, d=shift: k + d)
    if mapped:
        # Topics the preset does not cover, read through a --map file (written by main): the
        # ECM's pose and a force sensor, both sampled at the arm's times.
        Wrench, WrenchStamped, Vector3 = ts.types["geometry_msgs/msg/Wrench"], ts.types["geometry_msgs/msg/WrenchStamped"], ts.types["geometry_msgs/msg/Vector3"]

        def wrench(k, s):
            force, torque = Vector3(x=0.1 * k, y=0.0, z=-1.0), Vector3(x=0.0, y=0.0, z=-0.01 * k)
            return WrenchStamped(header=header(ts, ros1, s, "force_sensor"), wrench=Wrench(force=force, torque=torque))

        # A depth camera (16UC1) at the camera's times, read with --depth.
        add("/camera/depth/image", "sensor_msgs/msg/Image", streams["camera"], lambda k, s: depth_msg(ts, ros1, s, k), lambda k: k)
        expected["depths"] = [["depth", "/camera/depth/image"]]
        expected["ingest_args"] += ["--depth", "depth=/camera/depth/image"]
        add("/ECM/measured_cp", pose_type, streams["arm"], lambda k, s: pose_msg(ts, ros1, s, pose_values(k, 2.0), transform), lambda k: pose_values(k, 2.0))
        add("/force/wrench", "geometry_msgs/msg/WrenchStamped", streams["arm"], wrench, lambda k: [0.1 * k, -0.01 * k])
        expected["mapped"] = [
            {"name": "observation.meta.ecm_pose", "topic": "/ECM/measured_cp", "toml": 'values = "pose"'},
            {"name": "observation.meta.force", "topic": "/force/wrench", "toml": 'values = "fields"\nfields = ["wrench.force.x", "wrench.torque.z"]\nnames = ["fx", "tz"]'},
        ]
    # Each camera's intrinsics beside it, stated once (ROS 1 spells the matrices K, D, R, P).
    CameraInfo, RegionOfInterest = ts.types["sensor_msgs/msg/CameraInfo"], ts.types["sensor_msgs/msg/RegionOfInterest"]
    expected["camera_info"] = {}
    for c, (name, topic, _, _) in enumerate(cameras):
        k = [400.0 + c, 0.0, WIDTH / 2, 0.0, 401.0 + c, HEIGHT / 2, 0.0, 0.0, 1.0]
        d = [0.1, -0.05, 0.0, 0.0, 0.01]
        matrices = {"D": np.array(d), "K": np.array(k), "R": np.eye(3).reshape(-1), "P": np.array(k[:3] + [0.0] + k[3:6] + [0.0] + k[6:] + [0.0])}
        if not ros1:
            matrices = {key.lower(): value for key, value in matrices.items()}
        info = CameraInfo(header=header(ts, ros1, START_NS, f"{name}_optical"), height=HEIGHT, width=WIDTH, distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False), **matrices)
        out.append((START_NS + 1, topic.rsplit("/", 1)[0] + "/camera_info", "sensor_msgs/msg/CameraInfo", info))
        expected["camera_info"][name] = {"frame_id": f"{name}_optical", "k": k, "d": d}
    String = ts.types["std_msgs/msg/String"]
    # The instruction changes mid-episode (before the camera's dropout). A type without a
    # header: its time is when it was received.
    expected["streams"]["/instruction"] = []
    for at, text in ((START_NS, "grasp the needle"), (START_NS + 700_000_000, "lift the needle")):
        out.append((at, "/instruction", "std_msgs/msg/String", String(data=text)))
        expected["streams"]["/instruction"].append({"stamp": at, "receive": at, "value": text})
    if bimanual:
        # Each frame's instruction as a feature too, read by the loader.
        expected["ingest_args"].append("--instruction-text")
    out.append((START_NS + 5, "/unrelated", "std_msgs/msg/String", String(data="not mapped")))
    out.sort(key=lambda m: m[0])
    return out, expected


def write_ros1(path, seed, encoding, compression, bimanual=False, mapped=False):
    ts = get_typestore(Stores.ROS1_NOETIC)
    messages, expected = session_messages(ts, True, seed, encoding, bimanual=bimanual, mapped=mapped)
    writer = Ros1Writer(path)
    if compression:
        writer.set_compression(getattr(Ros1Writer.CompressionFormat, compression))
    with writer:
        connections = {}
        for receive, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], receive, ts.serialize_ros1(msg, msgtype))
    return expected


def write_ros2(path, seed, encoding, storage, split=False, transform=False, zstd_file=False):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    messages, expected = session_messages(ts, False, seed, encoding, transform=transform)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    parts = [messages[: len(messages) // 2], messages[len(messages) // 2:]] if split else [messages]
    names = []
    for p, part in enumerate(parts):
        folder = Path(f"{path}-part{p}") if split else Path(path)
        writer = Ros2Writer(folder, version=8, storage_plugin=plugin)
        if zstd_file:
            # Each storage file zstd-compressed whole, as `ros2 bag record --compression-mode file` does.
            writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
        with writer:
            connections = {}
            for receive, topic, msgtype, msg in part if p == 0 else messages:
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
                if (receive, topic) in {(m[0], m[1]) for m in part}:
                    writer.write(connections[topic], receive, ts.serialize_cdr(msg, msgtype))
        names.append(folder)
    if split:
        # One session over two files, as `ros2 bag record --max-bag-size` leaves it.
        target = Path(path)
        target.mkdir()
        files = []
        for p, folder in enumerate(names):
            storage_file = next(f for f in folder.iterdir() if f.name != "metadata.yaml")
            name = f"{target.name}_{p}{storage_file.suffix}"
            storage_file.rename(target / name)
            files.append(name)
            if p == 0:
                metadata = (folder / "metadata.yaml").read_text()
            (folder / "metadata.yaml").unlink()
            folder.rmdir()
        lines, out, skipping = metadata.splitlines(), [], False
        for line in lines:
            if line.strip().startswith("relative_file_paths:"):
                out.append(line)
                out.extend(f"  - {f}" for f in files)
                skipping = True
                continue
            if skipping and line.strip().startswith("- "):
                continue
            skipping = False
            out.append(line)
        (target / "metadata.yaml").write_text("\n".join(out) + "\n")
        if storage == "sqlite3":
            # As Humble and older write them: no definitions (built-in ones must serve).
            import sqlite3
            for name in files:
                db = sqlite3.connect(target / name)
                db.execute("DROP TABLE IF EXISTS message_definitions")
                db.commit()
                db.close()
    return expected


def write_single_mcap(path, seed, encoding):
    from mcap_ros2.writer import Writer as McapWriter
    ts = get_typestore(Stores.ROS2_HUMBLE)
    messages, expected = session_messages(ts, False, seed, encoding)
    schemas = {}
    from mcap.writer import CompressionType
    with open(path, "wb") as f:
        # lz4 chunks (the Python writer links blocks, as lz4.frame does by default).
        writer = McapWriter(f, compression=CompressionType.LZ4)
        for receive, topic, msgtype, msg in messages:
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_msgdef(msgtype, ts.generate_msgdef(msgtype, ros_version=2)[0])
            writer.write_message(topic, schemas[msgtype], to_dict(msg), log_time=receive, publish_time=receive)
        writer.finish()
    return expected


def to_dict(msg):
    """A rosbags message as the plain values mcap-ros2-support serialises."""
    if hasattr(msg, "__dataclass_fields__"):
        return {name: to_dict(getattr(msg, name)) for name in msg.__dataclass_fields__ if name != "__msgtype__"}
    if isinstance(msg, np.ndarray):
        return msg.tobytes() if msg.dtype == np.uint8 else msg.tolist()
    if isinstance(msg, list):
        return [to_dict(m) for m in msg]
    return msg


SESSIONS = {
    # name: (writer, kwargs)
    "ros1_raw_lz4.bag": (write_ros1, dict(seed=1, encoding="rgb8", compression="LZ4", mapped=True)),
    "ros1_mono_bz2.bag": (write_ros1, dict(seed=2, encoding="mono8", compression="BZ2")),
    "ros2_sqlite_split": (write_ros2, dict(seed=3, encoding="bgr8", storage="sqlite3", split=True, transform=True)),
    "ros2_mcap_jpeg": (write_ros2, dict(seed=4, encoding="jpeg", storage="mcap")),
    "single_png.mcap": (write_single_mcap, dict(seed=5, encoding="png")),
    "ros1_bimanual.bag": (write_ros1, dict(seed=6, encoding="rgb8", compression=None, bimanual=True)),
    "ros2_sqlite_zstd": (write_ros2, dict(seed=7, encoding="rgb8", storage="sqlite3", zstd_file=True)),
}


def write_bench(out, seconds):
    """One long uncompressed ROS 1 bag for the benchmark: 320 x 240 rgb8 at 30 Hz, the arm at
    100 Hz, no faults, images with sensor noise (scripts/bench_ingest.sh)."""
    global WIDTH, HEIGHT, SECONDS, NOISE
    WIDTH, HEIGHT, SECONDS, NOISE = 320, 240, seconds, 6
    ts = get_typestore(Stores.ROS1_NOETIC)
    messages, _ = session_messages(ts, True, 7, "rgb8", dropout=False, out_of_order=False)
    with Ros1Writer(out / "bench.bag") as writer:
        connections = {}
        for receive, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], receive, ts.serialize_ros1(msg, msgtype))
    print(f"wrote {out / 'bench.bag'}")


def main(out, bench=None):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if bench is not None:
        write_bench(out, bench)
        return
    for name, (writer, kwargs) in SESSIONS.items():
        expected = writer(str(out / name), **kwargs)
        if "mapped" in expected:
            map_file = (out / f"{name}.map.toml").resolve()
            map_file.write_text("".join(f'[[feature]]\nname = "{m["name"]}"\ntopic = "{m["topic"]}"\n{m["toml"]}\n\n' for m in expected["mapped"]))
            expected["ingest_args"] += ["--map", str(map_file)]
        if "depths" in expected:
            # lerobot 0.3.3 (Open-H's) takes three-channel image statistics only: no depth there.
            depth_args = {"--depth"} | {f"{name}={topic}" for name, topic in expected["depths"]}
            expected["open_h_args"] = [a for a in expected["ingest_args"] if a not in depth_args]
        if kwargs["seed"] % 2 == 1:
            # Episodes handed to the writer in parts of one batch of frames (about 32 frames;
            # the default parts are 32 MiB): the readers see the parts' row groups.
            expected["ingest_args"] += ["--part-mib", "0.001"]
            if "open_h_args" in expected:
                expected["open_h_args"] += ["--part-mib", "0.001"]
        (out / f"{name}.json").write_text(json.dumps(expected))
        print(f"wrote {out / name}")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[2] == "--bench":
        main(sys.argv[1], float(sys.argv[3]))
    else:
        main(sys.argv[1])
