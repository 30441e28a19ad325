#!/usr/bin/env bash
# Two builds of surgvla timed side by side on issue 48's edits, interleaved (this VM's steal
# time moves single runs by up to 10 %): each round runs the 40 % drop with every binary, then
# `cp -r` of the first binary's result, and the same `cp -r` followed by `sync` (the kept bytes
# on disk, as the edit leaves them: it syncs what it writes); then, with `split`, the 80/10/10
# split with every binary. Prints each run and the means and medians (wall seconds, task-clock
# ms with `perf` installed): single runs on this VM stray by up to 50 %, so compare medians over
# 16 rounds or more. Figures go to BENCHMARKS.md by hand.
#
#   scripts/bench_edit_ab.sh DATASET_AV1 ROUNDS OLD_BINARY NEW_BINARY [split] [cold] [slowdisk]
#
# DATASET_AV1: the input scripts/bench_edit.sh makes (the default dataset in AV1 video mode).
# The input's pages are first dropped from the page cache and read back in order: how a file's
# cached pages were made (large folios from a sequential read, or small ones from scattered
# reads and writes) changes what copying from it costs by up to 10x on this machine, so every
# run starts from the same state. `cold`: before each edit its input, and before each `cp` the
# result it copies, are dropped from the page cache (`posix_fadvise` DONTNEED after `sync`):
# both read from the disk. `slowdisk` (implies `cold`; root, Linux cgroups): every command
# reads the input's disk at 200 MiB/s at most (a cgroup's blkio throttle, or io.max), as a
# network or spinning disk would serve it: where the disk, not the CPU, sets the pace.
set -euo pipefail
if [ "$#" -lt 4 ]; then
    sed -n '2,21p' "$0" >&2
    exit 2
fi
input="$1" rounds="$2" old="$3" new="$4"
shift 4
split="" cold="" slowdisk=""
for flag in "$@"; do
    case "${flag}" in
    split) split=split ;;
    cold) cold=cold ;;
    slowdisk) slowdisk=slowdisk cold=cold ;;
    *) echo "unknown flag ${flag} (split, cold, slowdisk)" >&2; exit 2 ;;
    esac
done
work="$(mktemp -d "${TMPDIR:-/tmp}/surgvla-edit-ab.XXXXXX")"
group=""
leave_group() { # moves this shell back to the root cgroup and removes the throttled one
    if [ -n "${group}" ]; then
        echo $$ > "$(dirname "${group}")/cgroup.procs"
        rmdir "${group}"
    fi
}
trap 'leave_group; rm -rf "${work}"' EXIT
episodes="$(python3 -c "import json; print(json.load(open('${input}/meta/info.json'))['total_episodes'])")"
drop="$(python3 -c "print(','.join(str(i) for i in range(${episodes}) if i % 5 in (1, 3)))")"

uncache() { # DIR [reread]: drop DIR's files from the page cache (and read them back in order)
    sync
    python3 - "$@" <<'EOF'
import os, sys
for root, _, names in os.walk(sys.argv[1]):
    for name in sorted(names):
        fd = os.open(os.path.join(root, name), os.O_RDONLY)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        while len(sys.argv) > 2 and os.read(fd, 1 << 20):
            pass
        os.close(fd)
EOF
}
uncache "${input}" reread

throttle() { # from now on this shell and its commands read the input's disk at 200 MiB/s
    local device parent numbers rate=$((200 << 20))
    device="$(findmnt -no SOURCE -T "${input}")"
    parent="$(lsblk -ndo PKNAME "${device}" 2> /dev/null || true)"
    if [ -n "${parent}" ]; then device="/dev/${parent}"; fi
    numbers="$(lsblk -ndo MAJ:MIN "${device}" | tr -d ' ')"
    if [ -d /sys/fs/cgroup/blkio ]; then
        group="/sys/fs/cgroup/blkio/surgvla-bench-$$"
        mkdir "${group}"
        echo "${numbers} ${rate}" > "${group}/blkio.throttle.read_bps_device"
    else
        group="/sys/fs/cgroup/surgvla-bench-$$"
        echo +io > /sys/fs/cgroup/cgroup.subtree_control
        mkdir "${group}"
        echo "${numbers} rbps=${rate}" > "${group}/io.max"
    fi
    echo $$ > "${group}/cgroup.procs"
    echo "reads from ${device} (${numbers}) at ${rate} bytes/s at most" >&2
}
if [ -n "${slowdisk}" ]; then throttle; fi

timed() { # LABEL COMMAND... -> "LABEL wall S cpu MS"
    local label="$1"
    shift
    local cpu=""
    if command -v perf > /dev/null; then
        perf stat -x, -e task-clock -o "${work}/stat" /usr/bin/time -f "%e" -o "${work}/wall" \
            "$@" > /dev/null 2>&1 || { echo "failed: $*" >&2; exit 1; }
        cpu="$(grep task-clock "${work}/stat" | cut -d, -f1)"
    else
        /usr/bin/time -f "%e" -o "${work}/wall" "$@" > /dev/null 2>&1 ||
            { echo "failed: $*" >&2; exit 1; }
    fi
    echo "${label} wall $(cat "${work}/wall") cpu ${cpu:-0}"
}

for _ in $(seq "${rounds}"); do
    for binary in old new; do
        rm -rf "${work}/drop-${binary}"
        if [ -n "${cold}" ]; then uncache "${input}"; fi
        sync
        path="${old}"
        [ "${binary}" = new ] && path="${new}"
        timed "drop-${binary}" "${path}" edit "${input}" --drop "${drop}" --out "${work}/drop-${binary}"
    done
    rm -rf "${work}/copy"
    if [ -n "${cold}" ]; then uncache "${work}/drop-old"; fi
    sync
    timed "cp" cp -r "${work}/drop-old" "${work}/copy"
    rm -rf "${work}/copy"
    if [ -n "${cold}" ]; then uncache "${work}/drop-old"; fi
    sync
    timed "cp+sync" sh -c "cp -r '${work}/drop-old' '${work}/copy' && sync"
    if [ "${split}" = split ]; then
        for binary in old new; do
            rm -rf "${work}/split-${binary}"
            if [ -n "${cold}" ]; then uncache "${input}"; fi
            sync
            path="${old}"
            [ "${binary}" = new ] && path="${new}"
            timed "split-${binary}" "${path}" edit "${input}" \
                --split train=0.8,val=0.1,test=0.1 --out "${work}/split-${binary}"
        done
    fi
done | tee "${work}/runs" | sort -k1,1 -k3,3n | awk '
    { print; wall[$1] += $3; cpu[$1] += $5; n[$1]++; walls[$1, n[$1]] = $3 }
    END {
        for (k in wall) {
            # The runs of a label come sorted by wall time: the median is the middle one(s).
            m = n[k]; median = (walls[k, int((m + 1) / 2)] + walls[k, int(m / 2) + 1]) / 2
            printf "MEAN %-10s wall %.3f s (median %.3f s)  cpu %.0f ms  (%d runs)\n", k, wall[k] / m, median, cpu[k] / m, m
        }
    }'
