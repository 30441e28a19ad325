#!/usr/bin/env python3
"""Groups a perf profile's self time by pipeline stage (BENCHMARKS.md, issue 27).

    perf record -F 999 -o perf.data surgvla collect --episodes-per-task 13 --out D
    scripts/perf_stages.py perf.data

Prints each stage's share of all samples: symbols matched by the first stage whose pattern
fits (physics, rendering, image encoding, statistics, parquet, copies, allocator, kernel).
"""
import re
import subprocess
import sys

STAGES = {
    "physics": r"rapier|parry|psm|simulator|sincos|rem_pio2|nalgebra|simba|sim::|Isometry|Quaternion|task::|policy::|expert",
    "rendering": r"render::|raster|material|view::",
    "image encoding": r"fdeflate|png::|tiff|adler|encode_png",
    "statistics": r"stats::",
    "parquet, tables": r"ZSTD|HUF_|FSE_|HIST_|parquet|arrow|crc32|zstd|snap",
    "memcpy/memset": r"memmove|memset|memcpy",
    "allocator": r"malloc|free|unlink_chunk|_int_|cfree|realloc",
    "kernel": r"\[kernel",
}

report = subprocess.run(
    ["perf", "report", "-i", sys.argv[1], "--no-children", "--sort", "dso,symbol", "--stdio", "-g", "none"],
    capture_output=True, text=True, check=True,
).stdout
shares = {stage: 0.0 for stage in STAGES}
other = 0.0
for line in report.splitlines():
    match = re.match(r"\s+([0-9.]+)%\s+(.*)", line)
    if not match:
        continue
    share, symbol = float(match.group(1)), match.group(2)
    for stage, pattern in STAGES.items():
        if re.search(pattern, symbol):
            shares[stage] += share
            break
    else:
        other += share
for stage, share in shares.items():
    print(f"{stage:16} {share:5.1f} %")
print(f"{'other':16} {other:5.1f} %")
