#!/usr/bin/env bash
# Video decoding side by side (issue 25), in one run on this machine:
# 1. frames/s on one thread, demux + decode + RGB, on the same 224 x 224 AV1 (rav1e) and H.264
#    (openh264) files: surgvla (`cargo bench --bench export -- export/decode`, which writes the
#    files) against PyAV and, where it loads (it needs the system's FFmpeg), torchcodec, both
#    from the lerobot interop venv (.ci/run makes it);
# 2. `convert <the default dataset in video mode> --to rlds` on 2 threads: frames/s and peak
#    RSS, and the same for a 104-episode dataset (peak RSS flat in episodes).
# Part 2 collects the default dataset in AV1 video mode first (several minutes without `asm`).
# Figures go to BENCHMARKS.md by hand.
#
#   scripts/bench_decode.sh [PYTHON]     (default: the lerobot interop venv's python)
#   SURGVLA_BENCH_DECODE_ONLY=1 scripts/bench_decode.sh     (part 1 only)
set -euo pipefail
cd "$(dirname "$0")/.."
cache="${SURGVLA_CACHE:-${HOME}/.cache/surgvla}"
python="${1:-$(ls -d "${cache}"/venv-interop-*/bin/python 2>/dev/null | head -n 1)}"
if [[ -z "${python}" || ! -x "${python}" ]]; then
  echo "error: no Python with PyAV: give one, or run .ci/run once to make the lerobot venv" >&2
  exit 2
fi

echo "== surgvla (criterion, one thread)"
cargo bench --locked --bench export -- export/decode 2>/dev/null | grep -E "^export/decode|thrpt" | grep -v "%"
videos="target/tmp/bench-video"

echo "== PyAV and torchcodec (one thread, best of 5)"
"${python}" - "${videos}" <<'PY'
import sys, time
from pathlib import Path
import av

root = Path(sys.argv[1])


def best(run, repeats=5):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        frames = run()
        times.append(time.perf_counter() - start)
    return frames, min(times)


def pyav(path):
    def run():
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            stream.codec_context.thread_count = 1
            return sum(1 for frame in container.decode(stream) if frame.to_ndarray(format="rgb24") is not None)
    return run


try:
    from torchcodec.decoders import VideoDecoder
except Exception as error:  # no system FFmpeg
    VideoDecoder = None
    print(f"torchcodec: not loadable here ({type(error).__name__})")


def torchcodec(path):
    def run():
        decoder = VideoDecoder(str(path), num_ffmpeg_threads=1, dimension_order="NHWC", seek_mode="exact")
        return decoder.get_frames_in_range(0, len(decoder)).data.shape[0]
    return run


for codec in ["av1", "h264"]:
    path = root / codec / "videos/observation.images.endoscope/chunk-000/file-000.mp4"
    decoders = [("PyAV " + av.__version__, pyav(path))]
    if VideoDecoder is not None:
        import torchcodec as tc
        decoders.append(("torchcodec " + tc.__version__, torchcodec(path)))
    for name, run in decoders:
        frames, seconds = best(run)
        print(f"{codec}: {name}: {frames / seconds:,.0f} frames/s ({frames} frames)")
PY

if [[ "${SURGVLA_BENCH_DECODE_ONLY:-}" == 1 ]]; then
  exit 0
fi
echo "== convert <video dataset> --to rlds, 2 threads"
cargo build --release --locked --quiet
binary=target/release/surgvla
work="$(mktemp -d)"
trap 'rm -rf "${work}"' EXIT
"${binary}" collect --episodes-per-task 13 --video --out "${work}/small" >/dev/null 2>&1
"${binary}" collect --video --out "${work}/full" >/dev/null 2>&1
for input in small full; do
  frames="$("${binary}" info "${work}/${input}" --json | "${python}" -c 'import json,sys; print(json.load(sys.stdin)["frames"])')"
  rm -rf "${work}/rlds"
  /usr/bin/time -f "%e %M" -o "${work}/time" "${binary}" convert "${work}/${input}" --to rlds \
    --threads 2 --out "${work}/rlds" >/dev/null 2>&1
  read -r wall rss <"${work}/time"
  echo "${input}: ${frames} frames in ${wall} s: $("${python}" -c "print(f'{${frames} / ${wall}:,.0f}')") frames/s, peak RSS $((rss / 1024)) MB"
done
