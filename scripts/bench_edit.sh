#!/usr/bin/env bash
# `surgvla edit` beside lerobot 0.6.1's `lerobot-edit-dataset` and `cp` (issue 48), in one run on
# this machine, on the default 800-episode dataset in AV1 video mode:
# 1. dropping 40 % of the episodes (every index whose remainder by 5 is 1 or 3);
# 2. splitting it 80/10/10 (surgvla: seeded and stratified by task; lerobot: its own shuffle).
# Each is timed against `lerobot-edit-dataset` (delete_episodes, split) on a copy of the same
# input and against `cp -r` of surgvla's result (the kept bytes read and written once: the
# disk's limit). Wall time and peak RSS (/usr/bin/time), best of RUNS (lerobot's: one run).
# Figures go to BENCHMARKS.md by hand.
#
#   scripts/bench_edit.sh [DATASET_AV1] [RUNS]   (default: collects the default dataset and
#                                                 converts it to AV1; 3 runs; needs .ci/run's
#                                                 lerobot venv)
set -euo pipefail
cd "$(dirname "$0")/.."
cache="${SURGVLA_CACHE:-${HOME}/.cache/surgvla}"
venv="$(ls -d "${cache}"/venv-interop-*/ | head -n 1)"
work="target/tmp/bench-edit"
mkdir -p "${work}"
cargo build --release --locked --quiet
bin=target/release/surgvla
video="${1:-${work}/full-av1}"
runs="${2:-3}"
if [ ! -f "${video}/meta/info.json" ]; then
    "${bin}" collect --out "${work}/full"
    "${bin}" convert "${work}/full" --to lerobot --video av1 --out "${video}"
    rm -rf "${work}/full"
fi
episodes="$(python3 -c "import json; print(json.load(open('${video}/meta/info.json'))['total_episodes'])")"
drop_list="$(python3 -c "print(','.join(str(i) for i in range(${episodes}) if i % 5 in (1, 3)))")"
drop_json="[${drop_list}]"
export HF_HUB_OFFLINE=1 HF_HOME="${work}/huggingface"

time_once() { # COMMAND... -> "wall peak_rss_kb" of one run ("killed ..." when it was killed)
    local status=0
    /usr/bin/time -o "${work}/time" -f "%e %M" "$@" > "${work}/last.log" 2>&1 || status=$?
    # A command killed by a signal (the kernel's OOM killer) is reported, not a failure.
    if grep -q "terminated by signal" "${work}/time"; then
        echo "killed $(grep -o "signal [0-9]*" "${work}/time") $(tail -n 1 "${work}/time")"
        return
    fi
    if [ "${status}" -ne 0 ]; then
        tail -n 20 "${work}/last.log" >&2
        echo "failed (exit ${status}): $*" >&2
        exit 1
    fi
    tail -n 1 "${work}/time"
}
show() { # LABEL "wall rss" (or "killed wall rss")
    case "$2" in
        killed*)
            local rest="${2#killed signal }"
            printf '%-48s KILLED by signal %s (9: out of memory?) after %s s, peak RSS %s KB\n' \
                "$1" "${rest%% *}" "$(echo "${rest}" | cut -d' ' -f2)" "${rest##* }"
            ;;
        *) printf '%-48s wall %8s s  peak RSS %8s KB\n' "$1" "${2%% *}" "${2##* }" ;;
    esac
}
best() { # LABEL OUT COMMAND... -> the best wall time and its peak RSS over RUNS runs
    local label="$1" out="$2" result="" line
    shift 2
    for _ in $(seq "${runs}"); do
        rm -rf "${out}"
        sync
        line="$(time_once "$@")"
        if [ -z "${result}" ] || awk "BEGIN{exit !(${line%% *} < ${result%% *})}"; then
            result="${line}"
        fi
    done
    show "${label}" "${result}"
}
lerobot() { # LABEL OUT ARGS... -> lerobot-edit-dataset on a fresh copy of the input, once
    local label="$1" out="$2"
    shift 2
    # lerobot's datasets cache (tens of GB per split) is not kept from one run to the next.
    rm -rf "${work}/copy" "${out}"* "${HF_HOME}"
    cp -r "${video}" "${work}/copy"
    sync
    local result
    result="$(time_once "${venv}/bin/lerobot-edit-dataset" --repo_id local/input \
        --root "${work}/copy" "$@")"
    show "${label}" "${result}"
}

echo "input: ${video} (${episodes} episodes, $(du -sh "${video}" | cut -f1))"
echo "== drop 40 %"
best "surgvla edit --drop (40 %)" "${work}/dropped" \
    "${bin}" edit "${video}" --drop "${drop_list}" --out "${work}/dropped"
best "cp -r of its result" "${work}/dropped-cp" cp -r "${work}/dropped" "${work}/dropped-cp"
lerobot "lerobot-edit-dataset delete_episodes" "${work}/lerobot-dropped" \
    --new_repo_id local/dropped --new_root "${work}/lerobot-dropped" \
    --operation.type delete_episodes --operation.episode_indices "${drop_json}"
echo "== split 80/10/10"
best "surgvla edit --split" "${work}/split" \
    "${bin}" edit "${video}" --split train=0.8,val=0.1,test=0.1 --out "${work}/split"
best "cp -r of its results" "${work}/split-cp" cp -r "${work}/split" "${work}/split-cp"
lerobot "lerobot-edit-dataset split" "${work}/lerobot-split" \
    --new_root "${work}/lerobot-split" --operation.type split \
    --operation.splits '{"train": 0.8, "val": 0.1, "test": 0.1}'
du -sh "${work}/dropped" "${work}/split" "${work}"/lerobot-* 2>/dev/null || true
