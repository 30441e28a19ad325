#!/usr/bin/env bash
# The lossy-RGB tolerance (issue 25: `--verify` and `validate --replay` take a lossy frame at a
# PSNR of at least 30 dB): per-frame PSNR of JPEG quality 95 and 50 RLDS and of surgvla's AV1
# re-encoding against the PNG frames they came from, and of each frame against the next one (a
# one-step shift, which the tolerance must catch). Uses the interop venvs `.ci/run` makes (tfds
# for RLDS, PyAV for the video). Figures go to BENCHMARKS.md by hand.
#
#   scripts/lossy_psnr.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cache="${SURGVLA_CACHE:-${HOME}/.cache/surgvla}"
rlds_python="$(ls -d "${cache}"/venv-rlds-*/bin/python | head -n 1)"
lerobot_python="$(ls -d "${cache}"/venv-interop-*/bin/python | head -n 1)"
cargo build --release --locked --quiet
bin=target/release/surgvla
work="$(mktemp -d)"
trap 'rm -rf "${work}"' EXIT
"${bin}" collect --tasks T1-1 --episodes-per-task 2 --out "${work}/png" >/dev/null
"${bin}" convert "${work}/png" --to rlds --rlds-jpeg-quality 95 --out "${work}/q95" >/dev/null
"${bin}" convert "${work}/png" --to rlds --rlds-jpeg-quality 50 --out "${work}/q50" >/dev/null
"${bin}" convert "${work}/png" --to lerobot --video av1 --out "${work}/av1" >/dev/null
cat >"${work}/common.py" <<'PY'
import glob, io, sys
import numpy as np, pyarrow.parquet as pq
from PIL import Image
work = sys.argv[1]
rows = pq.read_table(glob.glob(f"{work}/png/data/*/*.parquet")[0]).to_pylist()
png = [np.asarray(Image.open(io.BytesIO(r["observation.images.endoscope"]["bytes"]))).astype(int) for r in rows]
def psnr(a, b):
    mse = ((a - b) ** 2).mean()
    return float("inf") if mse == 0 else 10 * np.log10(255 ** 2 / mse)
PY
TF_CPP_MIN_LOG_LEVEL=3 "${rlds_python}" - "${work}" <<'PY'
import sys; sys.path.insert(0, sys.argv[1]); from common import *
import tensorflow_datasets as tfds
for name in ["q95", "q50"]:
    builder = tfds.builder_from_directory(f"{work}/{name}/surgvla_benchmark/1.0.0")
    episodes = builder.as_dataset(split="train", read_config=tfds.ReadConfig(interleave_cycle_length=1))
    frames = [s["observation"]["image"].astype(int) for e in episodes for s in e["steps"].as_numpy_iterator()]
    print(f"JPEG {name}: lowest PSNR {min(psnr(a, b) for a, b in zip(png, frames)):.1f} dB over {len(frames)} frames")
shift = [psnr(png[i], png[i + 1]) for i in range(len(png) - 1) if rows[i]["episode_index"] == rows[i + 1]["episode_index"]]
print(f"one step late: median {np.median(shift):.1f} dB, highest {max(shift):.1f} dB, {np.mean(np.array(shift) < 30):.0%} of frames below 30 dB")
PY
"${lerobot_python}" - "${work}" <<'PY'
import sys; sys.path.insert(0, sys.argv[1]); from common import *
import av
frames = []
for path in sorted(glob.glob(f"{work}/av1/videos/*/*/*.mp4")):
    with av.open(path) as container:
        frames += [f.to_ndarray(format="rgb24").astype(int) for f in container.decode(video=0)]
print(f"AV1 re-encoded: lowest PSNR {min(psnr(a, b) for a, b in zip(png, frames)):.1f} dB over {len(frames)} frames")
PY
