"""The `surgvla` console script: the command line compiled into the module (the binary's code)."""

import signal
import sys


def main() -> None:
    """Runs `surgvla` with this process's arguments and exits with its code."""
    from surgvla._native import cli

    # Ctrl-C stops the command as it stops the binary (exit 130 by the signal), not through
    # Python's handler, which would wait for the command to return. A closed pipe is the
    # command's to handle, as in the binary (Rust ignores SIGPIPE too).
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    sys.exit(cli(["surgvla", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
