#!/usr/bin/env bash
# Whole-pipeline benchmark: the default `surgvla collect` (experts, verification by replay,
# rendering, LeRobot image mode), reporting its summary table (frames per second, time in
# physics, rendering, encoding and writing), wall time, CPU time and peak resident memory.
#
#   scripts/bench_pipeline.sh [episodes-per-task] [threads]
#   scripts/bench_pipeline.sh memory [threads]
#
# Default: 8 tasks x 100 episodes on all cores. `memory`: peak RSS of the default collection at
# about 100 and 1,000 episodes (8 tasks x 13 and x 125), which must not grow with the number of
# episodes. Figures go to BENCHMARKS.md by hand.
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

if [ "${1:-}" = memory ]; then
    threads="${2:-$(nproc)}"
    for episodes in 13 125; do
        echo "== 8 tasks x ${episodes} episodes, ${threads} threads"
        measure "${episodes}" "${threads}"
    done
else
    measure "${1:-100}" "${2:-$(nproc)}"
fi
