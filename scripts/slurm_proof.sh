#!/bin/bash
# Proves the Slurm job files on a real scheduler: starts a one-node Slurm cluster on this
# machine (munged, slurmctld and slurmd from Debian's packages, a generated slurm.conf with
# this host's CPUs, no accounting), submits examples/slurm/submit.sh twice through sbatch, and
# compares the merged datasets with one machine's runs byte for byte:
#   1. collect --episodes-per-task 2 in 4 shards, merged  == collect --episodes-per-task 2
#   2. convert (1.) --to rlds in 4 shards, merged          == convert (1.) --to rlds
# collect_report.json is left out of the comparison: it sums the shards' timings.
#
#   scripts/slurm_proof.sh [SURGVLA_BIN]       (as root; default target/release/surgvla)
#
# Installs slurmctld, slurmd, slurm-client and munge with apt-get when they are missing (they
# are test-only: the README's commands never need them). Every daemon it starts is stopped on
# exit, success or not; nothing is left in /etc or /run (the cluster lives in a temporary folder).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bin="$(realpath "${1:-$repo/target/release/surgvla}")"
[ -x "$bin" ] || { echo "no surgvla binary at $bin (cargo build --release)" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] || { echo "run as root: the daemons run as root here" >&2; exit 2; }

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    echo "installing Slurm and munge (Debian packages)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        slurmctld slurmd slurm-client munge >/dev/null
fi

work="$(mktemp -d /tmp/surgvla-slurm.XXXXXX)"
chmod 755 "$work"
conf="$work/slurm.conf"
export SLURM_CONF="$conf"
stop() {
    local status=$?
    scancel --quiet --user=root 2>/dev/null || true
    for pid in "$work"/slurmd.pid "$work"/slurmctld.pid "$work"/munged.pid; do
        if [ -s "$pid" ]; then
            kill "$(cat "$pid")" 2>/dev/null || true
        fi
    done
    # Wait for them to go, so that nothing is left running.
    for _ in $(seq 50); do
        pgrep -f "$work" >/dev/null || break
        sleep 0.2
    done
    pkill -9 -f "$work" 2>/dev/null || true
    if [ "$status" -ne 0 ]; then
        for log in "$work"/*.log "$work"/run*/logs/*; do
            [ -f "$log" ] && { echo "--- $log"; tail -n 20 "$log"; }
        done
    fi
    rm -rf "$work"
    exit "$status"
}
trap stop EXIT

host="$(hostname -s)"
cpus="$(nproc)"
mkdir -p "$work/state" "$work/spool" "$work/munge"
chmod 711 "$work/munge"
mungekey --create --keyfile="$work/munge/munge.key" --force
munged --key-file="$work/munge/munge.key" --socket="$work/munge/socket" \
    --pid-file="$work/munged.pid" --log-file="$work/munged.log" \
    --seed-file="$work/munge/seed" --force
cat > "$conf" <<CONF
ClusterName=surgvla
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$work/munge/socket
CredType=cred/munge
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MinJobAge=3600
NodeName=$host CPUs=$cpus State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
slurmctld -f "$conf"
slurmd -f "$conf"
for _ in $(seq 60); do
    if sinfo -h -o %T 2>/dev/null | grep -qE '^(idle|mixed|allocated)'; then
        break
    fi
    sleep 1
done
sinfo -h -o "%P %D %T %C" | sed 's/^/slurm: /'
sinfo -h -o %T | grep -qE '^(idle|mixed|allocated)' || { echo "the node did not come up" >&2; exit 1; }

# Waits for jobs to leave the queue, then checks each ended COMPLETED (scontrol keeps finished
# jobs for MinJobAge seconds; there is no accounting daemon for sacct).
wait_jobs() {
    local deadline=$((SECONDS + 1200))
    while [ -n "$(squeue -h -j "$(IFS=,; echo "$*")" 2>/dev/null)" ]; do
        [ "$SECONDS" -lt "$deadline" ] || { echo "jobs $* did not finish in 20 minutes" >&2; return 1; }
        sleep 2
    done
    local job state
    for job in "$@"; do
        for state in $(scontrol show job "$job" | grep -o 'JobState=[A-Z_]*' | cut -d= -f2); do
            if [ "$state" != COMPLETED ]; then
                echo "job $job ended $state" >&2
                return 1
            fi
        done
    done
}

# Runs submit.sh with SURGVLA_COMMAND=$2 into $1 and waits for both jobs.
run_on_slurm() {
    local out="$1" command="$2"
    local jobs
    jobs=$(SURGVLA_BIN="$bin" SURGVLA_OUT="$out" SURGVLA_COMMAND="$command" \
        "$repo/examples/slurm/submit.sh" 4)
    echo "slurm: submitted array and merge jobs $jobs ($command)"
    # shellcheck disable=SC2086
    wait_jobs $jobs
}

same() {
    if diff -r --exclude=collect_report.json "$1" "$2"; then
        echo "slurm: $3: the merged dataset equals one machine's byte for byte"
    else
        echo "slurm: $3: the merged dataset differs from one machine's" >&2
        return 1
    fi
}

"$bin" collect --episodes-per-task 2 --out "$work/single" --threads "$cpus" >"$work/single.log" 2>&1
run_on_slurm "$work/run-collect" "collect --episodes-per-task 2"
same "$work/single" "$work/run-collect/merged" "collect, 4 shards"

"$bin" convert "$work/single" --to rlds --out "$work/single-rlds" --threads "$cpus" >"$work/single-rlds.log" 2>&1
run_on_slurm "$work/run-convert" "convert $work/single --to rlds"
same "$work/single-rlds" "$work/run-convert/merged" "convert --to rlds, 4 shards"
