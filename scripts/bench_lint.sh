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
time_once() { # COMMAND... -> "wall peak_rss_kb" of one run
    /usr/bin/time -o "${work}/time" -f "%e %M" "$@" > /dev/null 2>&1 || true
    tail -n 1 "${work}/time"
}
faster() { # A B -> the faster of two "wall rss" lines (A when empty B)
    if [ -z "$1" ] || awk "BEGIN{exit !(${2%% *} < ${1%% *})}"; then echo "$2"; else echo "$1"; fi
}
show() { # LABEL "wall rss"
    printf '%-44s wall %6s s  peak RSS %7s KB\n' "$1" "${2%% *}" "${2##* }"
}
best() { # LABEL COMMAND... -> prints the best wall time and its peak RSS over RUNS runs
    local label="$1"
    shift
    local fastest=""
    for _ in $(seq "${runs}"); do
        fastest="$(faster "${fastest}" "$(time_once "$@")")"
    done
    show "${label}" "${fastest}"
}
# The full pass with and without the lint, run by turns (this machine's speed drifts over
# minutes: runs of one kind in a row would each see another machine).
by_turns() { # DATASET
    local lint="" plain=""
    for _ in $(seq "${runs}"); do
        lint="$(faster "${lint}" "$(time_once "${bin}" validate "$1")")"
        plain="$(faster "${plain}" "$(time_once "${bin}" validate --no-lint "$1")")"
    done
    show "surgvla validate (full, lint) $(basename "$1")" "${lint}"
    show "surgvla validate (full, --no-lint) $(basename "$1")" "${plain}"
}
frames="$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["total_frames"])' "${dataset}/meta/info.json")"
echo "== ${dataset} (${frames} frames) and ${video}"
for data in "${dataset}" "${video}"; do
    best "surgvla validate --quick --lint $(basename "${data}")" "${bin}" validate --quick --lint "${data}"
    best "lerobot-doctor check $(basename "${data}")" "${doctor}" check "${data}" --json
    # A first full read after doctor, which evicts the page cache: not timed.
    "${bin}" validate --no-lint "${data}" > /dev/null 2>&1 || true
    by_turns "${data}"
done
