#!/usr/bin/env bash
# Peak RSS of `collect --tasks T1-1` on 2 threads at 100, 1,000 and 3,000 episodes, three runs
# each (issue 24: the median at 3,000 within 10 % of the median at 100). About 10 minutes on 2
# cores. Figures go to BENCHMARKS.md by hand.
#
#   scripts/rss_episodes.sh [binary]
set -euo pipefail
cd "$(dirname "$0")/.."
binary="${1:-target/release/surgvla}"
if [[ $# -eq 0 ]]; then
  cargo build --release --locked --quiet
fi
work="$(mktemp -d)"
trap 'rm -rf "${work}"' EXIT
for episodes in 100 1000 3000; do
  for run in 1 2 3; do
    rm -rf "${work}/out"
    /usr/bin/time -f "${episodes} episodes, run ${run}: %e s wall, %M KB peak RSS" \
      "${binary}" collect --tasks T1-1 --episodes-per-task "${episodes}" --threads 2 \
      --out "${work}/out" 2>&1 >/dev/null | tail -1
  done
done
