"""The `surgvla` console script: the command line compiled into the module (the binary's code)."""

import sys


def main() -> None:
    """Runs `surgvla` with this process's arguments and exits with its code."""
    from surgvla._native import catch_interrupts, cli

    # Ctrl-C and SIGTERM stop the command as they stop the binary (it says what it kept and
    # exits 130), not through Python's handler, which would wait for the command to return.
    # A closed pipe is the command's to handle, as in the binary (Rust ignores SIGPIPE too).
    catch_interrupts()
    sys.exit(cli(["surgvla", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
