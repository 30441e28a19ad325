#!/usr/bin/env bash
# Byte-identity check between two builds of surgvla: the same collections (every format,
# LeRobot v3.0 / v2.1 / H.264 video), conversions of one dataset to every format, and a merge
# of two shards, written by each binary; every file's sha256 compared (collect_report.json,
# which holds timings, excluded). Prints the files that differ and exits 1 if any does.
# Usage: scripts/same_bytes.sh OLD_BINARY NEW_BINARY [WORK_DIR]
set -euo pipefail
old="$1" new="$2"
work="${3:-$(mktemp -d -t surgvla-same.XXXXXX)}"
small=(--tasks T1-1,T2-2,T3-2 --episodes-per-task 2 --threads 2)
make() { # BINARY OUT
    local bin="$1" out="$2"
    "${bin}" collect "${small[@]}" --with-mask --out "${out}/lerobot" >/dev/null
    "${bin}" collect "${small[@]}" --lerobot-version 2.1 --out "${out}/lerobot-v21" >/dev/null
    "${bin}" collect "${small[@]}" --video h264 --out "${out}/lerobot-h264" >/dev/null
    "${bin}" collect "${small[@]}" --video h264 --lerobot-version 2.1 --out "${out}/lerobot-h264-v21" >/dev/null
    "${bin}" collect "${small[@]}" --format rlds --rlds-shard-mb 1 --out "${out}/rlds" >/dev/null
    "${bin}" collect "${small[@]}" --format zarr --out "${out}/zarr" >/dev/null
    "${bin}" collect "${small[@]}" --format mcap --out "${out}/mcap" >/dev/null
    "${bin}" collect "${small[@]}" --format ply --out "${out}/ply" >/dev/null
    for to in rlds ply pcd mcap; do
        "${bin}" convert "${out}/lerobot" --to "${to}" --out "${out}/convert-${to}" >/dev/null
    done
    "${bin}" convert "${out}/lerobot" --to zarr --zarr-images --zarr-mask-channel --out "${out}/convert-zarr" >/dev/null
    "${bin}" convert "${out}/lerobot" --to lerobot --lerobot-version 2.1 --out "${out}/convert-v21" >/dev/null
    "${bin}" convert "${out}/rlds" --to lerobot --out "${out}/convert-from-rlds" >/dev/null
    # Video datasets copied (their spans and pixel statistics read back from the episodes table).
    "${bin}" convert "${out}/lerobot-h264" --to lerobot --video h264 --lerobot-version 2.1 --out "${out}/convert-h264-v21" >/dev/null
    "${bin}" convert "${out}/lerobot-h264-v21" --to lerobot --video h264 --out "${out}/convert-h264-v30" >/dev/null
    for i in 0 1; do
        "${bin}" collect "${small[@]}" --shard "${i}/2" --out "${out}/shard-${i}" >/dev/null
    done
    "${bin}" merge "${out}/shard-0" "${out}/shard-1" --out "${out}/merged" >/dev/null
    # Every format's merge, of all shards and of some (the collection records "merged 0/3,2/3").
    for format in lerobot rlds zarr mcap ply; do
        for i in 0 2; do
            "${bin}" collect "${small[@]}" --format "${format}" --shard "${i}/3" --out "${out}/${format}-third-${i}" >/dev/null
        done
        "${bin}" merge "${out}/${format}-third-0" "${out}/${format}-third-2" --out "${out}/${format}-some" >/dev/null
    done
    for i in 0 1; do
        "${bin}" collect "${small[@]}" --format zarr --shard "${i}/2" --out "${out}/zarr-half-${i}" >/dev/null
    done
    "${bin}" merge "${out}/zarr-half-1" "${out}/zarr-half-0" --out "${out}/zarr-merged" >/dev/null
}
make "${old}" "${work}/old"
make "${new}" "${work}/new"
sums() { (cd "$1" && find . -type f ! -name collect_report.json -print0 | sort -z | xargs -0 sha256sum); }
if diff <(sums "${work}/old") <(sums "${work}/new"); then
    echo "identical: $(sums "${work}/new" | wc -l) files"
else
    echo "the two builds wrote different bytes (above)" >&2
    exit 1
fi
