"""The quality lint against a corpus of planted defects, beside lerobot-doctor 0.2.0.

Each case copies a surgvla LeRobot dataset (image mode) and plants one defect with pyarrow:
`surgvla validate --json` must name it with the right check (an error where the defect is one
a trainer would mis-learn from), and, for the defects lerobot-doctor detects, doctor's own
report must flag it too (so the corpus holds what the peer calls a defect). The clean copy
must lint without an error, in the full pass and `--quick`. A copy given a second RGB camera
(the first's negative) must lint without a camera finding, and with the two cameras' pictures
traded from one episode's twelfth frame on, must have `camera-swap` name that episode and frame.

SURGVLA_BIN is the surgvla binary; SURGVLA_LEROBOT_DATASET a surgvla dataset (image mode).
"""

import json
import os
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
DOCTOR = str(Path(sys.executable).parent / "lerobot-doctor")


def source() -> Path:
    path = os.environ.get("SURGVLA_LEROBOT_DATASET")
    if not path:
        pytest.skip("SURGVLA_LEROBOT_DATASET is not set")
    return Path(path)


def black_png(width: int, height: int, channels: int) -> bytes:
    colour = {1: 0, 3: 2, 4: 6}[channels]
    raw = b"".join(b"\0" + bytes(width * channels) for _ in range(height))
    chunk = lambda kind, data: struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    header = struct.pack(">IIBBBBB", width, height, 8, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


class Table:
    """The dataset's data rows as numpy arrays, to plant in and write back."""

    def __init__(self, root: Path):
        self.files = sorted((root / "data").rglob("*.parquet"))
        self.tables = [pq.read_table(f) for f in self.files]
        self.table = pa.concat_tables(self.tables)
        self.episode = self.table.column("episode_index").to_numpy()

    def floats(self, name: str) -> np.ndarray:
        column = self.table.column(name).combine_chunks()
        width = column.type.list_size
        return column.values.to_numpy(zero_copy_only=False).reshape(-1, width).copy()

    def set_floats(self, name: str, values: np.ndarray):
        old = self.table.column(name).combine_chunks()
        flat = pa.array(values.astype(np.float32).ravel(), type=old.type.value_type)
        self.replace(name, pa.FixedSizeListArray.from_arrays(flat, old.type.list_size))

    def replace(self, name: str, array):
        index = self.table.schema.get_field_index(name)
        self.table = self.table.set_column(index, self.table.schema.field(index), array)

    def rows(self, episode: int) -> np.ndarray:
        return np.flatnonzero(self.episode == episode)

    def write(self):
        start = 0
        for path, old in zip(self.files, self.tables):
            part = self.table.slice(start, old.num_rows)
            start += old.num_rows
            pq.write_table(part, path)


def action_lag(t: Table):
    action = t.floats("action")
    for e in np.unique(t.episode):
        rows = t.rows(e)
        action[rows[2:]] = action[rows[:-2]]
    t.set_floats("action", action)


def frozen_actions(t: Table):
    action = t.floats("action")
    rows = t.rows(1)
    start = len(rows) // 3
    action[rows[start:start + len(rows) // 4]] = action[rows[start]] + np.float32(0.002)
    t.set_floats("action", action)


def action_jump(t: Table):
    action = t.floats("action")
    action[t.rows(2)[20], :6] += 0.5
    t.set_floats("action", action)


def nan_action(t: Table):
    action = t.floats("action")
    action[t.rows(0)[5], 1] = np.nan
    t.set_floats("action", action)


def timestamp_gap(t: Table):
    stamps = t.table.column("timestamp").to_numpy().copy()
    rows = t.rows(3)
    stamps[rows[10:]] += np.float32(0.6)
    t.replace("timestamp", pa.array(stamps, type=pa.float32()))


def state_outlier(t: Table):
    state = t.floats("observation.state")
    state[t.rows(4)[12], 0] += 0.5
    t.set_floats("observation.state", state)


def gripper_out_of_range(t: Table):
    action = t.floats("action")
    action[t.rows(1)[7], 6] = 1.5
    t.set_floats("action", action)


def quaternion_not_unit(t: Table):
    env = t.floats("observation.environment_state")
    env[t.rows(2), 3:7] *= 1.2
    t.set_floats("observation.environment_state", env)


def millimetres(t: Table):
    state = t.floats("observation.state")
    state[:, :3] *= 1000.0
    t.set_floats("observation.state", state)


def epoch_timestamps(t: Table):
    stamps = t.table.column("timestamp").to_numpy().astype(np.float64) + 1.7e9
    t.replace("timestamp", pa.array(stamps.astype(np.float32), type=pa.float32()))


def pose_jump(t: Table):
    state = t.floats("observation.state")
    rows = t.rows(5)
    state[rows[len(rows) // 2:], 0] += 0.06
    t.set_floats("observation.state", state)


def image_column(t: Table, name: str, change):
    column = t.table.column(name).combine_chunks()
    images = column.field("bytes").to_pylist()
    change(images)
    t.replace(name, pa.StructArray.from_arrays([pa.array(images, type=pa.binary()), column.field("path")], fields=list(column.type)))


def blank_camera(t: Table):
    def change(images):
        for row in t.rows(2):
            images[row] = black_png(224, 224, 3)
    image_column(t, "observation.images.endoscope", change)


def frozen_camera(t: Table):
    state = t.floats("observation.state")
    rows = t.rows(0)
    # Where the tool moves: five frames from the first that moves on.
    start = next(i for i in range(1, len(rows) - 6) if np.abs(state[rows[i + 5]] - state[rows[i]]).max() > 1e-3)

    def change(images):
        for row in rows[start + 1:start + 6]:
            images[row] = images[rows[start]]
    image_column(t, "observation.images.endoscope", change)


# (defect, plant, surgvla's check, is an error, what lerobot-doctor says of it: a phrase of its
# report, or None where doctor does not judge it)
CASES = [
    ("nan", nan_action, "finite", True, "NaN"),
    ("frozen-actions", frozen_actions, "frozen-action", False, "frozen"),
    ("action-jump", action_jump, "action-jump", False, "action jump"),
    ("timestamp-gap", timestamp_gap, "timestamps", True, "dropped frame"),
    ("outlier", state_outlier, "outliers", False, "outlier"),
    ("action-lag", action_lag, "action-lag", True, None),
    ("gripper-range", gripper_out_of_range, "gripper-range", True, None),
    ("quaternion", quaternion_not_unit, "quaternion", True, None),
    ("millimetres", millimetres, "units", True, None),
    ("epoch-timestamps", epoch_timestamps, "epoch-timestamps", True, None),
    ("pose-jump", pose_jump, "pose-jump", False, None),
    ("blank-camera", blank_camera, "blank-camera", True, None),
    ("frozen-camera", frozen_camera, "frozen-camera", True, None),
]


def planted(tmp_path: Path, plant) -> Path:
    root = tmp_path / "dataset"
    shutil.copytree(source(), root)
    (root / "meta/surgvla_manifest.json").unlink(missing_ok=True)
    if plant is not None:
        table = Table(root)
        plant(table)
        table.write()
    return root


def validate(root: Path, *flags: str) -> tuple[int, dict]:
    run = subprocess.run([BIN, "validate", str(root), "--json", *flags], capture_output=True, text=True)
    return run.returncode, json.loads(run.stdout)


def doctor(root: Path) -> list[str]:
    run = subprocess.run([DOCTOR, "check", str(root), "--json"], capture_output=True, text=True)
    report = json.loads(run.stdout)
    return [m["message"] for c in report["checks"] for m in c["messages"] if m["severity"] != "PASS"]


def test_the_clean_copy_lints_without_an_error(tmp_path):
    root = planted(tmp_path, None)
    for flags in [(), ("--quick",)]:
        code, report = validate(root, *flags)
        assert code == 0, report["errors"]
        assert report["lint"], "the lint ran"
        assert all(line["status"] != "error" for line in report["lint"]), report["lint"]
    # A warning fails the dataset only when asked.
    code, report = validate(root, "--fail-on", "warning")
    assert code == (1 if report["warnings"] else 0)
    code, report = validate(root, "--no-lint")
    assert code == 0 and report["lint"] == []


@pytest.mark.parametrize("name,plant,check,is_error,doctor_says", CASES, ids=[c[0] for c in CASES])
def test_each_planted_defect_is_found_by_its_check(tmp_path, name, plant, check, is_error, doctor_says):
    root = planted(tmp_path, plant)
    code, report = validate(root)
    found = report["errors"] if is_error else report["warnings"]
    assert any(f["check"] == check for f in found), (name, [(f["check"], f["message"]) for f in report["errors"] + report["warnings"]])
    if is_error:
        assert code == 1
    lint_line = [line for line in report["lint"] if line["check"] == check]
    if lint_line:
        # A lint check: its summary line says what it found.
        assert lint_line[0]["status"] != "ok", lint_line
    else:
        # A structural check: its finding names the episode.
        assert any(f["check"] == check and f.get("episode") is not None for f in found), found
    if doctor_says is not None:
        said = doctor(root)
        assert any(doctor_says.lower() in m.lower() for m in said), (name, said)


def inverted_png(png: bytes) -> bytes:
    """The picture's negative (255 - every sample), for an 8-bit RGB PNG whose rows are all
    Paeth-filtered (surgvla's): Paeth chooses alike on negated neighbours, so each filtered
    byte is negated, bar the first pixel's (predicted from nothing)."""
    at, chunks = 8, []
    while at < len(png):
        (length,) = struct.unpack(">I", png[at:at + 4])
        chunks.append((png[at + 4:at + 8], png[at + 8:at + 8 + length]))
        at += 12 + length
    header = dict(chunks)[b"IHDR"]
    width, height, depth, colour = struct.unpack(">IIBB", header[:10])
    assert (depth, colour) == (8, 2)
    rows = np.frombuffer(zlib.decompress(b"".join(d for k, d in chunks if k == b"IDAT")), np.uint8)
    rows = rows.reshape(height, 1 + width * 3).copy()
    assert (rows[:, 0] == 4).all(), "Paeth rows"
    rows[:, 1:] = (256 - rows[:, 1:].astype(np.int32)) % 256
    rows[0, 1:4] = 255 - (256 - rows[0, 1:4].astype(np.int32)) % 256
    chunk = lambda kind, data: struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows.tobytes())) + chunk(b"IEND", b"")


def negated_stats(stats: dict) -> dict:
    """Statistics (of 0..1 samples) of the negative picture."""
    one = lambda values: (1.0 - np.asarray(values, dtype=np.float64)).tolist()
    flipped = {"min": one(stats["max"]), "max": one(stats["min"]), "mean": one(stats["mean"]), "std": stats["std"], "count": stats["count"]}
    for low, high in [("q01", "q99"), ("q10", "q90"), ("q50", "q50")]:
        if low in stats:
            flipped[low], flipped[high] = one(stats[high]), one(stats[low])
    return flipped


def with_second_camera(root: Path, swap_episode: int | None):
    """A second RGB camera (the first's negative) beside the first, declared in info.json with
    its statistics; with `swap_episode`, the two cameras' pictures trade places from that
    episode's twelfth frame on."""
    first, second = "observation.images.endoscope", "observation.images.endoscope_negative"
    info_path = root / "meta/info.json"
    info = json.loads(info_path.read_text())
    info["features"][second] = info["features"][first]
    info_path.write_text(json.dumps(info, indent=4))
    stats_path = root / "meta/stats.json"
    stats = json.loads(stats_path.read_text())
    stats[second] = negated_stats(stats[first])
    stats_path.write_text(json.dumps(stats, indent=4))
    for path in sorted((root / "meta/episodes").rglob("*.parquet")):
        table = pq.read_table(path)
        prefix = f"stats/{first}/"
        partner = {"min": "max", "max": "min", "mean": "mean", "q01": "q99", "q99": "q01", "q10": "q90", "q90": "q10", "q50": "q50"}
        for name in [n for n in table.column_names if n.startswith(prefix)]:
            key, kind = name[len(prefix):], table.schema.field(name).type
            if key in partner:
                values = [(1.0 - np.asarray(v, dtype=np.float64)).tolist() for v in table.column(prefix + partner[key]).to_pylist()]
            else:  # std and count are the negative's too
                values = table.column(name).to_pylist()
            table = table.append_column(pa.field(f"stats/{second}/{key}", kind), pa.array(values, type=kind))
        pq.write_table(table, path)
    t = Table(root)
    column = t.table.column(first).combine_chunks()
    images = column.field("bytes").to_pylist()
    negatives = [inverted_png(png) for png in images]
    if swap_episode is not None:
        for row in t.rows(swap_episode)[12:]:
            images[row], negatives[row] = negatives[row], images[row]
    t.replace(first, pa.StructArray.from_arrays([pa.array(images, type=pa.binary()), column.field("path")], fields=list(column.type)))
    paths = pa.array([None] * len(negatives), type=column.field("path").type)
    t.table = t.table.append_column(second, pa.StructArray.from_arrays([pa.array(negatives, type=pa.binary()), paths], fields=list(column.type)))
    t.write()


@pytest.mark.parametrize("swap_episode", [None, 3])
def test_two_cameras_swapped_within_an_episode_and_not(tmp_path, swap_episode):
    root = planted(tmp_path, None)
    with_second_camera(root, swap_episode)
    code, report = validate(root)
    assert code == 0, [(f["check"], f["message"]) for f in report["errors"]]
    swaps = [f for f in report["warnings"] if f["check"] == "camera-swap"]
    if swap_episode is None:
        assert swaps == [], swaps
        assert [w["check"] for w in report["warnings"] if w["check"] in ("blank-camera", "frozen-camera")] == []
    else:
        # Found at the first frame both cameras' pictures were looked at after the swap.
        assert [(f["episode"], f["frame"]) for f in swaps] == [(swap_episode, 12)], swaps
        line = [line for line in report["lint"] if line["check"] == "camera-swap"]
        assert line and line[0]["status"] == "warning", line
