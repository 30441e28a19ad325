#!/usr/bin/env bash
# Sharded conversion and merge, timed: the default collection (800 episodes), then for each
# target format the whole conversion, the same conversion as 4 shards run one after the other
# (on 4 machines each takes its own time: the slowest is the wall time of a sharded run), the
# merge of the 4, and a byte comparison of the merged dataset with the whole conversion.
#
#   scripts/bench_shards.sh [SURGVLA_BIN] [FORMATS...]   (default: target/release/surgvla; rlds zarr mcap)
set -euo pipefail

bin="$(realpath "${1:-target/release/surgvla}")"
shift || true
formats=("${@:-rlds zarr mcap}")
read -r -a formats <<<"${formats[*]}"
work="$(mktemp -d -t surgvla-shards.XXXXXX)"
trap 'rm -rf "${work}"' EXIT
timed() { # prints "wall s, user+sys CPU-s, peak RSS MB" of a command
    /usr/bin/time -f "%e s wall, %U+%S CPU-s, %M KB peak" "$@" 2>&1 >/dev/null | tail -n 1
}
echo "collect (800 episodes): $(timed "${bin}" collect --out "${work}/full")"
for to in "${formats[@]}"; do
    echo "convert --to ${to}, whole: $(timed "${bin}" convert "${work}/full" --to "${to}" --out "${work}/${to}")"
    for i in 0 1 2 3; do
        echo "  --shard ${i}/4: $(timed "${bin}" convert "${work}/full" --to "${to}" --shard "${i}/4" --out "${work}/${to}-${i}")"
    done
    echo "  merge of the 4: $(timed "${bin}" merge "${work}/${to}"-{3,2,1,0} --out "${work}/${to}-merged")"
    if diff -r "${work}/${to}" "${work}/${to}-merged" >/dev/null; then
        echo "  merged == whole, byte for byte"
    else
        echo "  merged differs from whole" >&2
        exit 1
    fi
    rm -rf "${work:?}/${to}" "${work:?}/${to}"-*
done
