#!/usr/bin/env bash
# Whole-pipeline benchmark: the default `surgvla collect` (experts, verification by replay,
# rendering, LeRobot image mode), reporting its summary table (frames per second, time in
# physics, rendering, encoding and writing), wall time, CPU time and peak resident memory.
#
#   scripts/bench_pipeline.sh [episodes-per-task] [threads]
#   scripts/bench_pipeline.sh memory [threads]
#   scripts/bench_pipeline.sh rlds [threads]
#   scripts/bench_pipeline.sh datasets [threads]
#   scripts/bench_pipeline.sh scaling [episodes-per-task]
#   scripts/bench_pipeline.sh compare OLD_BINARY [NEW_BINARY] [rounds]
#
# Default: 8 tasks x 100 episodes on all cores. `memory`: peak RSS of the default collection at
# about 100 and 1,000 episodes (8 tasks x 13 and x 125), which must not grow with the number of
# episodes. `rlds`: `convert --to rlds` of the default 800-episode dataset and of a 104-episode
# one (wall time, peak RSS flat in the number of episodes), then `collect --format rlds` of the
# default dataset; with SURGVLA_RLDS_PYTHON (the RLDS interop venv's python) tensorflow_datasets
# then reads all 800 episodes, compares every step with the LeRobot dataset and the collected RLDS
# with the converted one (tests/interop/rlds). `datasets`: on the default 800-episode dataset,
# `validate --quick`, `validate` (every frame), `validate --replay`, `info`, `convert --to
# lerobot --lerobot-version 2.1 --verify`; then the same collection as two shards, `merge`d and
# compared byte for byte with the single run. `video`: the default dataset in video mode
# (H.264), `convert` to v2.1 and back (compared byte for byte with the original), two video
# shards `merge`d (compared with the single run), `validate`; and the image-mode dataset
# converted to v2.1 and to RLDS, its PNG and TIFF bytes copied. `scaling`: the default collect
# on one thread pinned to one core (`taskset`, so the writer thread cannot borrow a second one),
# then on 2, 4, ... threads up to the machine's cores: frames per second and the speed-up over
# one core. `compare`: the default collect with an older binary and this one (or NEW_BINARY)
# back to back, `rounds` times (2), the same machine and hour: wall, CPU and peak RSS of each,
# and their summary lines. Figures go to BENCHMARKS.md by hand.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked --quiet
work="$(mktemp -d)"
trap 'rm -rf "${work}"' EXIT

# Runs one collection; prints wall, CPU and peak RSS.
measure() {
    local episodes="$1" threads="$2"
    /usr/bin/time -v ./target/release/surgvla collect --episodes-per-task "${episodes}" \
        --threads "${threads}" --out "${work}/dataset" >"${work}/stdout" 2>"${work}/time"
    grep -E "Elapsed \(wall clock\)|User time|System time|Maximum resident set size" "${work}/time"
    tail -n 1 "${work}/stdout"
    du -sh "${work}/dataset"
    rm -rf "${work}/dataset"
}

# Runs one command under /usr/bin/time; prints its last line, wall, CPU and peak RSS.
timed() {
    /usr/bin/time -v "$@" >"${work}/stdout" 2>"${work}/time"
    tail -n 1 "${work}/stdout"
    grep -E "Elapsed \(wall clock\)|User time|System time|Maximum resident set size" "${work}/time"
}

if [ "${1:-}" = rlds ]; then
    threads="${2:-$(nproc)}"
    surgvla=./target/release/surgvla
    for episodes in 13 100; do
        echo "== convert --to rlds: 8 tasks x ${episodes} episodes, ${threads} threads"
        "${surgvla}" collect --episodes-per-task "${episodes}" --threads "${threads}" --out "${work}/lerobot-${episodes}" | tail -n 1
        timed "${surgvla}" convert "${work}/lerobot-${episodes}" --to rlds --threads "${threads}" --out "${work}/rlds-${episodes}"
        du -sh "${work}/rlds-${episodes}"
    done
    echo "== collect --format rlds: 8 tasks x 100 episodes, ${threads} threads"
    timed "${surgvla}" collect --threads "${threads}" --format rlds --out "${work}/rlds-collected"
    if [ -n "${SURGVLA_RLDS_PYTHON:-}" ]; then
        echo "== tensorflow_datasets reads the 800 episodes and compares every step"
        SURGVLA_LEROBOT_DATASET="${work}/lerobot-100" SURGVLA_RLDS_DATASET="${work}/rlds-100" \
            SURGVLA_RLDS_CONVERTED="${work}/rlds-collected" \
            "${SURGVLA_RLDS_PYTHON}" -m pytest -q -p no:cacheprovider tests/interop/rlds
    fi
elif [ "${1:-}" = datasets ]; then
    threads="${2:-$(nproc)}"
    surgvla=./target/release/surgvla
    echo "== the default dataset: 8 tasks x 100 episodes, ${threads} threads"
    timed "${surgvla}" collect --threads "${threads}" --out "${work}/data"
    echo "== validate --quick"
    timed "${surgvla}" validate --quick "${work}/data"
    echo "== validate (every frame)"
    timed "${surgvla}" validate --threads "${threads}" "${work}/data"
    echo "== validate --replay"
    timed "${surgvla}" validate --replay --threads "${threads}" "${work}/data"
    echo "== info"
    timed "${surgvla}" info "${work}/data"
    echo "== convert --to lerobot --lerobot-version 2.1 --verify"
    timed "${surgvla}" convert "${work}/data" --to lerobot --lerobot-version 2.1 --threads "${threads}" --out "${work}/v21" --verify
    rm -rf "${work}/v21"
    echo "== two shards, merged"
    for shard in 0 1; do
        "${surgvla}" collect --threads "${threads}" --shard "${shard}/2" --out "${work}/shard-${shard}" | tail -n 1
    done
    timed "${surgvla}" merge "${work}/shard-0" "${work}/shard-1" --threads "${threads}" --out "${work}/merged"
    if diff -r -x collect_report.json "${work}/data" "${work}/merged" >/dev/null; then
        echo "merged = single run, byte for byte (collect_report.json aside)"
    else
        echo "merged differs from the single run" >&2
        exit 1
    fi
elif [ "${1:-}" = video ]; then
    threads="${2:-$(nproc)}"
    surgvla=./target/release/surgvla
    # Every file but the report (timings) and the manifest's options digest (the encoder's
    # quality, which a copy does not know); the manifests' file lists are compared.
    same() {
        diff -r -x collect_report.json -x surgvla_manifest.json "$1" "$2" >/dev/null &&
            diff <(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["files"])' "$1/meta/surgvla_manifest.json") \
                <(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["files"])' "$2/meta/surgvla_manifest.json") >/dev/null
    }
    echo "== the default dataset in video mode (H.264), ${threads} threads"
    timed "${surgvla}" collect --threads "${threads}" --video h264 --out "${work}/video"
    echo "== convert video --to lerobot --lerobot-version 2.1 (samples copied)"
    timed "${surgvla}" convert "${work}/video" --to lerobot --lerobot-version 2.1 --threads "${threads}" --out "${work}/video21"
    echo "== and back to v3.0"
    timed "${surgvla}" convert "${work}/video21" --to lerobot --threads "${threads}" --out "${work}/video30"
    same "${work}/video" "${work}/video30" && echo "v3.0 -> v2.1 -> v3.0 = the original, byte for byte"
    echo "== validate (video: sample tables and spans)"
    timed "${surgvla}" validate --threads "${threads}" "${work}/video"
    echo "== two video shards, merged"
    for shard in 0 1; do
        "${surgvla}" collect --threads "${threads}" --video h264 --shard "${shard}/2" --out "${work}/vshard-${shard}" | tail -n 1
    done
    timed "${surgvla}" merge "${work}/vshard-0" "${work}/vshard-1" --threads "${threads}" --out "${work}/vmerged"
    same "${work}/video" "${work}/vmerged" && echo "merged video = single run, byte for byte"
    rm -rf "${work}/video"*  "${work}/vshard-"* "${work}/vmerged"
    echo "== the default dataset in image mode; PNG and TIFF bytes copied by convert"
    "${surgvla}" collect --threads "${threads}" --out "${work}/data" | tail -n 1
    timed "${surgvla}" convert "${work}/data" --to lerobot --lerobot-version 2.1 --threads "${threads}" --out "${work}/v21"
    timed "${surgvla}" convert "${work}/data" --to rlds --threads "${threads}" --out "${work}/rlds"
elif [ "${1:-}" = scaling ]; then
    episodes="${2:-100}"
    cores="$(nproc)"
    one=""
    threads=1
    while [ "${threads}" -le "${cores}" ]; do
        pin=()
        if [ "${threads}" = 1 ] && command -v taskset >/dev/null; then pin=(taskset -c 0); fi
        started="$(date +%s.%N)"
        "${pin[@]}" ./target/release/surgvla collect --episodes-per-task "${episodes}" \
            --threads "${threads}" --out "${work}/dataset" >"${work}/stdout"
        secs="$(echo "$(date +%s.%N) - ${started}" | bc -l)"
        frames="$(grep -o '[0-9]* frames' "${work}/stdout" | tail -n 1 | cut -d' ' -f1)"
        one="${one:-${secs}}"
        printf '%2d threads: %6.1f s, %6.0f frames/s, %4.2fx one core\n' "${threads}" "${secs}" \
            "$(echo "${frames} / ${secs}" | bc -l)" "$(echo "${one} / ${secs}" | bc -l)"
        rm -rf "${work}/dataset"
        threads=$((threads * 2))
    done
elif [ "${1:-}" = compare ]; then
    old="${2:?the older binary}"
    new="${3:-./target/release/surgvla}"
    for round in $(seq "${4:-2}"); do
        for binary in "${old}" "${new}"; do
            echo "== round ${round}: ${binary}"
            /usr/bin/time -f "wall %e s, CPU %U + %S s, peak RSS %M kB" "${binary}" collect \
                --out "${work}/dataset" 2>&1 | tail -n 3
            rm -rf "${work}/dataset"
        done
    done
elif [ "${1:-}" = memory ]; then
    threads="${2:-$(nproc)}"
    for episodes in 13 125; do
        echo "== 8 tasks x ${episodes} episodes, ${threads} threads"
        measure "${episodes}" "${threads}"
    done
else
    measure "${1:-100}" "${2:-$(nproc)}"
fi
