"""The wheel's `surgvla` command (a console script running the CLI compiled into the module)
behaves as the binary: the same output, the same exit codes, and Ctrl-C stops it by the signal
as it stops the binary (Python's own SIGINT handler would wait for the command to return).

SURGVLA_BIN: the binary built by cargo, to compare with.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
SCRIPT = Path(sys.executable).parent / "surgvla"


def run(program, *args):
    return subprocess.run([str(program), *args], capture_output=True, text=True, timeout=120)


def test_the_same_output_and_exit_codes_as_the_binary(tmp_path):
    assert SCRIPT.is_file(), SCRIPT
    for args, code in [
        (["tasks"], 0),
        (["--version"], 0),
        (["eval", "--bogus"], 2),
        (["validate", str(tmp_path / "nothing")], 2),
        (["sim", "--task", "T1-1", "--seed", "3"], 0),
    ]:
        ours, theirs = run(SCRIPT, *args), run(BIN, *args)
        assert (ours.returncode, ours.stdout, ours.stderr) == (code, theirs.stdout, theirs.stderr), args
        assert theirs.returncode == code, args


def test_ctrl_c_stops_the_command_as_it_stops_the_binary(tmp_path):
    codes = []
    for program in (SCRIPT, BIN):
        out = tmp_path / program.__str__().replace("/", "_")
        child = subprocess.Popen(
            [str(program), "collect", "--episodes-per-task", "200", "--threads", "1", "--out", str(out)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(3)
        assert child.poll() is None, f"{program} ended before the signal"
        child.send_signal(signal.SIGINT)
        codes.append(child.wait(timeout=30))
    # Killed by the signal (-2 here, 130 in a shell), or exit 130 once the command catches it.
    assert codes[0] == codes[1] and codes[0] in (-signal.SIGINT, 130), codes
