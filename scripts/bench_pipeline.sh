#!/usr/bin/env bash
# Whole-pipeline benchmark: the default `surgvla collect` (experts, verification by replay,
# rendering, LeRobot image mode), reporting its summary table (frames per second, time in
# physics, rendering, encoding and writing), wall time, CPU time and peak resident memory.
#
#   scripts/bench_pipeline.sh [episodes-per-task] [threads]
#
# Default: 8 tasks x 100 episodes on all cores. Figures go to BENCHMARKS.md by hand.
set -euo pipefail
cd "$(dirname "$0")/.."
episodes="${1:-100}"
threads="${2:-$(nproc)}"
cargo build --release --locked --quiet
out="$(mktemp -d)/dataset"
log="$(mktemp)"
/usr/bin/time -v ./target/release/surgvla collect --episodes-per-task "${episodes}" --threads "${threads}" --out "${out}" 2>"${log}"
grep -E "Elapsed \(wall clock\)|User time|System time|Maximum resident set size" "${log}"
du -sh "${out}"
rm -rf "$(dirname "${out}")" "${log}"
