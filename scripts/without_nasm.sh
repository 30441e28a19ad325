#!/usr/bin/env bash
# Runs a command where the `nasm` assembler is absent, as on a fresh machine: in a private
# mount namespace, every `nasm` on PATH is covered by /dev/null, which cannot be executed. Nothing
# outside this process sees the change and nothing stays mounted. CI builds and runs the README's
# commands this way, so a build step that needs nasm (rav1e's `asm` feature, opt-in) fails CI
# even on a machine where an earlier run installed it.
#
# Needs root (or CAP_SYS_ADMIN) for the mount namespace.
#
# usage: scripts/without_nasm.sh COMMAND [ARGS...]
set -euo pipefail

if [ "${SURGVLA_WITHOUT_NASM:-}" != 1 ]; then
    if ! unshare --mount true 2>/dev/null; then
        echo "error: $0 needs mount namespaces (run as root: unshare --mount)" >&2
        exit 1
    fi
    SURGVLA_WITHOUT_NASM=1 exec unshare --mount bash "$0" "$@"
fi

IFS=: read -r -a path_dirs <<<"${PATH}"
for dir in "${path_dirs[@]}"; do
    if [ -e "${dir}/nasm" ]; then
        mount --bind /dev/null "${dir}/nasm"
    fi
done
if nasm -v >/dev/null 2>&1; then
    echo "error: $0 could not hide nasm ($(command -v nasm))" >&2
    exit 1
fi
exec "$@"
