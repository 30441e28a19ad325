#!/usr/bin/env bash
# Ingest side by side (issue 41), in one run on this machine, on the same ROS 1 bag: a 320 x 240
# rgb8 camera at 30 Hz and a dVRK arm at 100 Hz (setpoints at 50 Hz), SECONDS long, written by
# rosbags (tests/interop/ingest/make_bags.py --bench), into LeRobot v3.0 image mode:
# 1. surgvla ingest (2 threads);
# 2. the Python route contributors use today: rosbags' AnyReader, numpy synchronisation by the
#    same rule (searchsorted), lerobot 0.6.1's LeRobotDataset.create / add_frame / save_episode.
# Wall time and peak RSS (/usr/bin/time) of each; the frames both write are compared.
# Figures go to BENCHMARKS.md by hand.
#
#   scripts/bench_ingest.sh [SECONDS]      (default 60; needs .ci/run's lerobot and ingest venvs)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
cache="${SURGVLA_CACHE:-${HOME}/.cache/surgvla}"
lerobot_python="$(ls -d "${cache}"/venv-interop-*/bin/python | head -n 1)"
ingest_python="${SURGVLA_INGEST_PYTHON:-$(ls -d "${cache}"/venv-ingest-*/bin/python | head -n 1)}"
work="target/tmp/bench-ingest"
rm -rf "${work}" && mkdir -p "${work}"
# rosbags for the lerobot venv's Python (3.12), beside it, not in it.
"${lerobot_python}" -m pip install --quiet --disable-pip-version-check --no-deps --target "${work}/site" \
    rosbags==0.11.9 apsw==3.54.1.0 backports.zstd==1.8.0 lz4==4.4.5 ruamel.yaml==0.19.1 >/dev/null
"${ingest_python}" tests/interop/ingest/make_bags.py "${work}" --bench "${seconds}"
ls -l "${work}/bench.bag"
cargo build --release --locked --quiet

echo "== surgvla ingest"
/usr/bin/time -f "wall %e s, peak RSS %M KB" target/release/surgvla ingest "${work}/bench.bag" \
    --camera left=/camera/left/image --threads 2 --out "${work}/surgvla"

echo "== rosbags + numpy + LeRobotDataset.add_frame"
PYTHONPATH="${work}/site" HF_HUB_OFFLINE=1 HF_HOME="${work}/hf" /usr/bin/time -f "wall %e s, peak RSS %M KB" \
    "${lerobot_python}" - "${work}/bench.bag" "${work}/python" <<'PY'
import sys
from pathlib import Path
import numpy as np
from rosbags.highlevel import AnyReader
from lerobot.datasets.lerobot_dataset import LeRobotDataset

bag, out = Path(sys.argv[1]), Path(sys.argv[2])
FPS = 30
TOLERANCE = 1_500_000_000 // FPS
SAMPLED = ["/PSM1/measured_cp", "/PSM1/jaw/measured_js", "/camera/left/image"]
EVENTS = ["/PSM1/setpoint_cp", "/PSM1/jaw/setpoint_js"]
streams = {t: ([], []) for t in SAMPLED + EVENTS}
task = ""
with AnyReader([bag]) as reader:
    for connection, _, raw in reader.messages():
        msg = reader.deserialize(raw, connection.msgtype)
        if connection.topic == "/instruction":
            task = msg.data
            continue
        if connection.topic not in streams:
            continue
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if connection.topic.endswith("_cp"):
            p, q = msg.pose.position, msg.pose.orientation
            value = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])
        elif connection.topic.endswith("_js"):
            value = float(msg.position[0])
        else:
            value = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)
        streams[connection.topic][0].append(stamp)
        streams[connection.topic][1].append(value)
stamps = {t: np.array(s) for t, (s, _) in streams.items()}
start = max(stamps[t].min() for t in SAMPLED)
end = min(stamps[t].max() for t in SAMPLED)
grid = start + np.arange((end - start) * FPS // 1_000_000_000 + 1) * 1_000_000_000 // FPS
picks, ok = {}, np.ones(len(grid), dtype=bool)
for t in SAMPLED + EVENTS:
    order = np.argsort(stamps[t], kind="stable")
    i = np.searchsorted(stamps[t][order], grid, side="right") - 1
    ok &= i >= 0
    picked = order[np.maximum(i, 0)]
    if t in SAMPLED:
        ok &= grid - stamps[t][picked] <= TOLERANCE
    picks[t] = picked
features = {
    "observation.images.left": {"dtype": "image", "shape": (240, 320, 3), "names": ["height", "width", "channels"]},
    "observation.state": {"dtype": "float32", "shape": (8,), "names": None},
    "action": {"dtype": "float32", "shape": (8,), "names": None},
}
dataset = LeRobotDataset.create("local/bench", FPS, features, root=out, robot_type="dvrk", use_videos=False)
frames = 0
for k in np.nonzero(ok)[0]:
    value = lambda t: streams[t][1][picks[t][k]]
    dataset.add_frame({
        "observation.images.left": value("/camera/left/image"),
        "observation.state": np.concatenate([value("/PSM1/measured_cp"), [value("/PSM1/jaw/measured_js")]]).astype(np.float32),
        "action": np.concatenate([value("/PSM1/setpoint_cp"), [value("/PSM1/jaw/setpoint_js")]]).astype(np.float32),
        "task": task,
    })
    frames += 1
dataset.save_episode()
dataset.finalize()
print(f"wrote {frames} frames")
PY

echo "== the same frames"
HF_HUB_OFFLINE=1 HF_HOME="${work}/hf" "${lerobot_python}" - "${work}" <<'PY'
import sys
from pathlib import Path
import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset
work = Path(sys.argv[1])
ours = LeRobotDataset("local/ours", root=work / "surgvla")
theirs = LeRobotDataset("local/theirs", root=work / "python")
print(f"surgvla {ours.num_frames} frames, python {theirs.num_frames} frames")
assert ours.num_frames == theirs.num_frames
for i in range(0, ours.num_frames, 97):
    a, b = ours[i], theirs[i]
    for key in ("observation.state", "action", "observation.images.left"):
        assert np.array_equal(a[key].numpy(), b[key].numpy()), (i, key)
print("every sampled frame equal")
PY
