#!/usr/bin/env bash
# validate's quality lint side by side with lerobot-doctor 0.2.0 (issue 42), in one run on this
# machine, on the default 800-episode dataset (image mode) and its AV1 conversion:
# 1. `surgvla validate --quick --lint` (no pixel decoding) against `lerobot-doctor check`
#    (which decodes no image frame either: it opens each video file's first frame);
# 2. the full pass (every frame decoded) with the lint and with `--no-lint`: the lint's cost.
# Wall time and peak RSS (/usr/bin/time) of each, best of RUNS. Figures go to BENCHMARKS.md by
# hand.
#
#   scripts/bench_lint.sh [DATASET] [RUNS]   (default: collects the default dataset; 3 runs;
#                                             needs .ci/run's doctor venv)
set -euo pipefail
cd "$(dirname "$0")/.."
cache="${SURGVLA_CACHE:-${HOME}/.cache/surgvla}"
doctor="$(ls -d "${cache}"/venv-doctor-*/bin/lerobot-doctor | head -n 1)"
work="target/tmp/bench-lint"
mkdir -p "${work}"
cargo build --release --locked --quiet
bin=target/release/surgvla
dataset="${1:-${work}/full}"
runs="${2:-3}"
if [ ! -f "${dataset}/meta/info.json" ]; then
    "${bin}" collect --out "${dataset}"
fi
video="${work}/full-av1"
if [ ! -f "${video}/meta/info.json" ]; then
    "${bin}" convert "${dataset}" --to lerobot --video av1 --out "${video}"
fi
best() { # LABEL COMMAND... -> prints the best wall time and its peak RSS over RUNS runs
    local label="$1"
    shift
    local fastest=""
    for _ in $(seq "${runs}"); do
        /usr/bin/time -o "${work}/time" -f "%e %M" "$@" > /dev/null 2>&1 || true
        local line
        line="$(tail -n 1 "${work}/time")"
        local wall="${line%% *}"
        if [ -z "${fastest}" ] || awk "BEGIN{exit !(${wall} < ${fastest%% *})}"; then
            fastest="${line}"
        fi
    done
    printf '%-44s wall %6s s  peak RSS %7s KB\n' "${label}" "${fastest%% *}" "${fastest##* }"
}
frames="$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["total_frames"])' "${dataset}/meta/info.json")"
echo "== ${dataset} (${frames} frames) and ${video}"
for data in "${dataset}" "${video}"; do
    best "surgvla validate --quick --lint $(basename "${data}")" "${bin}" validate --quick --lint "${data}"
    best "lerobot-doctor check $(basename "${data}")" "${doctor}" check "${data}" --json
    best "surgvla validate (full, lint) $(basename "${data}")" "${bin}" validate "${data}"
    best "surgvla validate (full, --no-lint) $(basename "${data}")" "${bin}" validate --no-lint "${data}"
done
