#!/bin/bash
# Submits the whole run to Slurm: N shard tasks, then the merge once they all succeed.
#
#   SURGVLA_BIN=/shared/bin/surgvla SURGVLA_OUT=/shared/run1 \
#   SURGVLA_COMMAND="collect --episodes-per-task 100" examples/slurm/submit.sh 16
#
# Prints the two job ids (array, merge). Extra sbatch options (a partition, an account) go in
# SBATCH_* variables, which sbatch reads itself (e.g. SBATCH_PARTITION=gpu).
set -euo pipefail

shards="${1:?usage: submit.sh SHARDS (the number of array tasks)}"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
: "${SURGVLA_OUT:?set SURGVLA_OUT to a folder every node sees}"
export SURGVLA_BIN="${SURGVLA_BIN:-surgvla}" SURGVLA_OUT SURGVLA_COMMAND="${SURGVLA_COMMAND:-collect}"
mkdir -p "$SURGVLA_OUT/logs"
array=$(sbatch --parsable --array="0-$((shards - 1))" --export=ALL \
    --output="$SURGVLA_OUT/logs/shard-%A_%a.out" "$here/shard.sbatch")
array="${array%%;*}"
merge=$(sbatch --parsable --dependency="afterok:$array" --export=ALL \
    --output="$SURGVLA_OUT/logs/merge-%j.out" "$here/merge.sbatch")
echo "$array ${merge%%;*}"
