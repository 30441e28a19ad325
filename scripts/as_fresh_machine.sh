#!/usr/bin/env bash
# Runs a command as on a fresh machine, where neither the `nasm` assembler nor the test-only
# system packages `.ci/run` installs for the interop tests (libusb-1.0, which Open3D loads, and
# FFmpeg, whose libraries torchcodec loads) are present: in a private mount namespace, every
# `nasm`, `ffmpeg` and `ffprobe` on PATH and every such library file the dynamic loader knows is
# covered by /dev/null, which can be neither executed nor loaded.
# Nothing outside this process sees the change and nothing stays mounted. CI builds and runs the
# README's commands this way, so a build or run step that needs nasm (rav1e's `asm` feature,
# opt-in) or a test-only library fails CI even on a machine where an earlier run installed it.
#
# Needs root (or CAP_SYS_ADMIN) for the mount namespace.
#
# usage: scripts/as_fresh_machine.sh COMMAND [ARGS...]
set -euo pipefail

if [ "${SURGVLA_AS_FRESH_MACHINE:-}" != 1 ]; then
    if ! unshare --mount true 2>/dev/null; then
        echo "error: $0 needs mount namespaces (run as root: unshare --mount)" >&2
        exit 1
    fi
    SURGVLA_AS_FRESH_MACHINE=1 exec unshare --mount bash "$0" "$@"
fi

IFS=: read -r -a path_dirs <<<"${PATH}"
for dir in "${path_dirs[@]}"; do
    for tool in nasm ffmpeg ffprobe; do
        if [ -e "${dir}/${tool}" ]; then
            mount --bind /dev/null "${dir}/${tool}"
        fi
    done
done
for tool in nasm ffmpeg; do
    if "${tool}" -version >/dev/null 2>&1 || "${tool}" -v >/dev/null 2>&1; then
        echo "error: $0 could not hide ${tool} ($(command -v "${tool}"))" >&2
        exit 1
    fi
done

# The test-only libraries: each file the loader's cache names, and what its links point to.
hidden=()
while read -r library; do
    for file in "${library}" "$(readlink -f "${library}")"; do
        if [ -f "${file}" ] && [ -s "${file}" ]; then
            mount --bind /dev/null "${file}"
            hidden+=("${file}")
        fi
    done
done < <(ldconfig -p | awk '/libusb-1\.0\.so|libav(codec|format|util|filter|device)\.so|libsw(scale|resample)\.so/ {print $NF}')
for file in "${hidden[@]}"; do
    if [ -s "${file}" ]; then
        echo "error: $0 could not hide ${file}" >&2
        exit 1
    fi
done
exec "$@"
