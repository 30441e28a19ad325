#!/usr/bin/env bash
# A full disk mid-collection: `surgvla collect` must stop with exit 1 and an error naming the file
# and the full disk, leave a dataset that does not look complete (no meta/info.json, the
# incomplete marker present), and `collect --resume` must finish it, once space is freed, to the
# same bytes as an uninterrupted run. A read-only output exits 2.
#
# Needs root (or CAP_SYS_ADMIN): it mounts a 4 MB tmpfs in a private mount namespace, so nothing
# outside this process sees it and nothing is left mounted.
#
# usage: scripts/check_full_disk.sh path/to/surgvla SCRATCH_DIR
set -euo pipefail

if [ "${SURGVLA_IN_MOUNT_NAMESPACE:-}" != 1 ]; then
    if ! unshare --mount true 2>/dev/null; then
        echo "error: $0 needs mount namespaces (run as root: unshare --mount)" >&2
        exit 1
    fi
    SURGVLA_IN_MOUNT_NAMESPACE=1 exec unshare --mount bash "$0" "$@"
fi

bin="$(realpath "$1")"
scratch="$2"
disk="${scratch}/small-disk"
mkdir -p "${disk}"
mount -t tmpfs -o size=4m tmpfs "${disk}"

# Four T1-1 episodes are about 6 MB; 1 MB data files make checkpoints before the disk fills.
args=(collect --tasks T1-1 --episodes-per-task 4 --data-file-mb 1)
fail() {
    echo "full-disk check failed: $*" >&2
    exit 1
}

set +e
"${bin}" "${args[@]}" --out "${disk}/ds" >"${scratch}/full.out" 2>"${scratch}/full.err"
code=$?
set -e
cat "${scratch}/full.err"
[ "${code}" = 1 ] || fail "exit code ${code}, expected 1"
grep -q "^error: ${disk}/ds/data/chunk-000/file-[0-9]*\.parquet: .*No space left on device" "${scratch}/full.err" ||
    fail "the error does not name the data file and the cause"
grep -q "the disk is full" "${scratch}/full.err" || fail "no full-disk hint"
grep -q -- "--resume" "${scratch}/full.err" || fail "the hint does not say --resume continues it"
[ ! -e "${disk}/ds/meta/info.json" ] || fail "an interrupted dataset has meta/info.json"
[ -e "${disk}/ds/.surgvla-incomplete" ] || fail "the incomplete marker is missing"

mount -o remount,size=64m tmpfs "${disk}"
resumed="$("${bin}" "${args[@]}" --out "${disk}/ds" --resume 2>&1)"
grep -q "^resuming .* at episode [1-9]" <<<"${resumed}" || fail "resume did not start from a checkpoint: ${resumed}"
[ -e "${disk}/ds/meta/info.json" ] || fail "the resumed dataset has no meta/info.json"
[ ! -e "${disk}/ds/.surgvla-incomplete" ] || fail "the resumed dataset still has the incomplete marker"

"${bin}" "${args[@]}" --out "${scratch}/reference" >/dev/null
# The report's timing differs between runs; everything else must be the same bytes.
diff -r --exclude=collect_report.json "${disk}/ds" "${scratch}/reference" >/dev/null ||
    fail "the resumed dataset differs from an uninterrupted run"
echo "full disk: exit 1 naming the file, no info.json; --resume after freeing space gives the uninterrupted bytes"

# A read-only output is the user's to fix: exit 2 naming it, for a new folder and an empty one.
readonly_disk="${scratch}/read-only"
mkdir -p "${readonly_disk}"
mount -t tmpfs -o size=1m,ro tmpfs "${readonly_disk}"
for out in "${readonly_disk}/ds" "${readonly_disk}"; do
    set +e
    "${bin}" "${args[@]}" --out "${out}" 2>"${scratch}/ro.err" >/dev/null
    code=$?
    set -e
    [ "${code}" = 2 ] || fail "a read-only --out ${out}: exit ${code}, expected 2"
    grep -q "Read-only file system" "${scratch}/ro.err" || fail "the error does not say read-only: $(cat "${scratch}/ro.err")"
done
echo "read-only output: exit 2 naming it"
