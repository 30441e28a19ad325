"""Open X-Embodiment datasets as tensorflow_datasets writes them, converted by surgvla: six
published feature specs (keys, dtypes, tensor and image shapes as on the TFDS catalogue pages:
fractal20220817_data, bridge, taco_play, jaco_play, language_table and
austin_buds_dataset_converted_externally_to_rlds), each built by a real tfds builder with a few
short episodes of synthetic values, converted to LeRobot and to RLDS and read back with
pyarrow and tensorflow_datasets.

What must hold: the instruction wherever the spec keeps it (fractal's
`observation/natural_language_instruction`, language_table's int32 byte codes) becomes the task;
an action dict becomes one `action` in OpenVLA's order with its parts named; a state is found
where the spec keeps it; every other step feature is carried with its values, and what cannot be
(nothing in these specs) is named on stderr, per-episode values become columns of LeRobot's
episodes table; `validate` of every output exits 0.

SURGVLA_BIN is the surgvla binary; SURGVLA_OXE_OUT, when set, receives the LeRobot conversions
for lerobot's own loader (tests/interop/oxe).
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
import pytest  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402

BIN = os.environ.get("SURGVLA_BIN", "surgvla")
F32, I32, BOOL = np.float32, np.int32, np.bool_


def tensor(*shape, dtype=F32):
    return tfds.features.Tensor(shape=shape, dtype=dtype)


def scalar(dtype=F32):
    return tfds.features.Scalar(dtype=dtype)


def image(h, w, c=3, dtype=np.uint8):
    return tfds.features.Image(shape=(h, w, c), dtype=dtype)


TEXT = "text"
FLAGS = {"is_first": scalar(BOOL), "is_last": scalar(BOOL), "is_terminal": scalar(BOOL)}

# Each spec: (step features, episode features, where the instruction is, the action's parts in
# OpenVLA's order, the state's parts). TEXT marks a text feature.
SPECS = {
    "fractal20220817_data": (
        {
            "action": {
                "base_displacement_vector": tensor(2), "base_displacement_vertical_rotation": tensor(1),
                "gripper_closedness_action": tensor(1), "rotation_delta": tensor(3),
                "terminate_episode": tensor(3, dtype=I32), "world_vector": tensor(3),
            },
            "discount": scalar(), "reward": scalar(),
            "observation": {
                "base_pose_tool_reached": tensor(7), "gripper_closed": tensor(1),
                "gripper_closedness_commanded": tensor(1), "height_to_bottom": tensor(1),
                "image": image(256, 320), "natural_language_embedding": tensor(512),
                "natural_language_instruction": TEXT, "orientation_box": tensor(2, 3),
                "orientation_start": tensor(4), "robot_orientation_positions_box": tensor(3, 3),
                "rotation_delta_to_go": tensor(3), "src_rotation": tensor(4), "vector_to_go": tensor(3),
                "workspace_bounds": tensor(3, 3),
            },
        },
        {},
        ("observation", "natural_language_instruction"),
        ["world_vector", "rotation_delta", "gripper_closedness_action"],
        ["base_pose_tool_reached", "gripper_closed"],
    ),
    "bridge": (
        {
            "action": {
                "open_gripper": scalar(BOOL), "rotation_delta": tensor(3),
                "terminate_episode": scalar(), "world_vector": tensor(3),
            },
            "discount": scalar(), "reward": scalar(),
            "observation": {
                "image": image(480, 640), "natural_language_embedding": tensor(512),
                "natural_language_instruction": TEXT, "state": tensor(7),
            },
        },
        {},
        ("observation", "natural_language_instruction"),
        ["world_vector", "rotation_delta", "open_gripper"],
        ["state"],
    ),
    "taco_play": (
        {
            "action": {
                "actions": tensor(7), "rel_actions_gripper": tensor(7),
                "rel_actions_world": tensor(7), "terminate_episode": scalar(),
            },
            "discount": scalar(), "reward": scalar(),
            "observation": {
                "depth_gripper": tensor(84, 84), "depth_static": tensor(150, 200),
                "natural_language_embedding": tensor(512), "natural_language_instruction": TEXT,
                "rgb_gripper": image(84, 84), "rgb_static": image(150, 200), "robot_obs": tensor(15),
                "structured_language_instruction": TEXT,
            },
        },
        {},
        ("observation", "natural_language_instruction"),
        ["rel_actions_world"],
        ["robot_obs"],
    ),
    "jaco_play": (
        {
            "action": {
                "gripper_closedness_action": tensor(1), "terminate_episode": tensor(3, dtype=I32),
                "world_vector": tensor(3),
            },
            "discount": scalar(), "reward": scalar(),
            "observation": {
                "end_effector_cartesian_pos": tensor(7), "end_effector_cartesian_velocity": tensor(6),
                "image": image(224, 224), "image_wrist": image(224, 224), "joint_pos": tensor(8),
                "natural_language_embedding": tensor(512), "natural_language_instruction": TEXT,
            },
        },
        {},
        ("observation", "natural_language_instruction"),
        ["world_vector", "gripper_closedness_action"],
        ["end_effector_cartesian_pos"],
    ),
    "language_table": (
        {
            "action": tensor(2), "reward": scalar(),
            "observation": {
                "effector_target_translation": tensor(2), "effector_translation": tensor(2),
                "instruction": tensor(512, dtype=I32), "rgb": image(360, 640),
            },
        },
        {"episode_id": TEXT},
        ("observation", "instruction"),
        None,
        ["effector_translation"],
    ),
    "austin_buds_dataset_converted_externally_to_rlds": (
        {
            "action": tensor(7), "discount": scalar(), "reward": scalar(),
            "language_embedding": tensor(512), "language_instruction": TEXT,
            "observation": {"image": image(128, 128), "state": tensor(24), "wrist_image": image(128, 128)},
        },
        {"episode_metadata": {"file_path": TEXT}},
        ("language_instruction",),
        None,
        ["state"],
    ),
    # Held out: added after the conversions were built, and the one spec with depth images
    # (uint16, 1/1024 m) and per-step camera matrices; zarr, MCAP and point clouds are made of
    # it with --camera and --depth.
    "maniskill_dataset_converted_externally_to_rlds": (
        {
            "action": tensor(7), "discount": scalar(), "reward": scalar(),
            "language_embedding": tensor(512), "language_instruction": TEXT,
            "observation": {
                "base_pose": tensor(7), "depth": image(256, 256, 1, np.uint16), "image": image(256, 256),
                "main_camera_cam2world_gl": tensor(4, 4), "main_camera_extrinsic_cv": tensor(4, 4),
                "main_camera_intrinsic_cv": tensor(3, 3), "state": tensor(18),
                "target_object_or_part_final_pose": tensor(7),
                "target_object_or_part_final_pose_valid": tensor(7, dtype=np.uint8),
                "target_object_or_part_initial_pose": tensor(7),
                "target_object_or_part_initial_pose_valid": tensor(7, dtype=np.uint8),
                "tcp_pose": tensor(7), "wrist_camera_cam2world_gl": tensor(4, 4),
                "wrist_camera_extrinsic_cv": tensor(4, 4), "wrist_camera_intrinsic_cv": tensor(3, 3),
                "wrist_depth": image(256, 256, 1, np.uint16), "wrist_image": image(256, 256),
            },
        },
        {"episode_metadata": {"episode_id": TEXT, "file_path": TEXT}},
        ("language_instruction",),
        None,
        ["state"],
    ),
}

INSTRUCTIONS = ["pick up the gauze", "place the can upright", "push the red star to the corner"]


def features_of(tree):
    """tfds features for a spec tree (TEXT -> Text)."""
    if tree == TEXT:
        return tfds.features.Text()
    if isinstance(tree, dict):
        return {k: features_of(v) for k, v in tree.items()}
    return tree


def value_of(feature, key, rng, text, step, steps):
    """A synthetic value for one leaf: smooth images (they compress), seeded numbers."""
    if key in FLAGS:
        return {"is_first": step == 0, "is_last": step == steps - 1, "is_terminal": step == steps - 1}[key]
    if feature == TEXT:
        return text
    if isinstance(feature, dict):
        return {k: value_of(v, k, rng, text, step, steps) for k, v in feature.items()}
    if isinstance(feature, tfds.features.Image):
        h, w, c = feature.shape
        ramp = np.add.outer(np.arange(h), np.arange(w)) + 17 * step
        if feature.np_dtype == np.uint16:  # depth in millimetres, beyond 8 bits
            return (ramp[:, :, None] * 97 + 300).astype(np.uint16)
        return np.repeat((ramp % 256)[:, :, None], c, axis=2).astype(np.uint8)
    if key == "instruction":  # language_table: UTF-8 byte codes, zero-padded
        codes = np.zeros(512, np.int32)
        codes[: len(text)] = list(text.encode())
        return codes
    shape, dtype = feature.shape, feature.np_dtype
    if dtype == np.bool_:
        return bool(rng.integers(0, 2))
    if np.issubdtype(dtype, np.integer):
        return rng.integers(0, 2, shape).astype(dtype)
    return rng.standard_normal(shape).astype(dtype) if shape else dtype(rng.standard_normal())


def builder_class(name, spec):
    step, episode, _, _, _ = spec
    step = {**step, **FLAGS}

    def _info(self):
        return tfds.core.DatasetInfo(
            builder=self, citation=f"@misc{{{name}, title={{{name}}}}}", license="CC-BY-4.0",
            features=tfds.features.FeaturesDict({"steps": tfds.features.Dataset(features_of(step)), **features_of(episode)}),
        )

    def _split_generators(self, dl_manager):
        return {"train": self._generate_examples()}

    def _generate_examples(self):
        rng = np.random.default_rng(7)
        for e in range(2):
            steps, text = 3 + e, INSTRUCTIONS[e]
            record = {"steps": [value_of(step, None, rng, text, i, steps) for i in range(steps)]}
            for key, leaf in episode.items():
                record[key] = value_of(leaf, key, rng, f"episode {e}", 0, 1)
            yield f"episode_{e}", record

    namespace = {
        "name": name, "VERSION": tfds.core.Version("0.1.0"), "_info": _info,
        "_split_generators": _split_generators, "_generate_examples": _generate_examples,
    }
    return type(name, (tfds.core.GeneratorBasedBuilder,), namespace, skip_registration=True)


def build(name, tmp_path_factory):
    data_dir = tmp_path_factory.mktemp(name[:20])
    builder = builder_class(name, SPECS[name])(data_dir=str(data_dir))
    builder.download_and_prepare()
    return name, Path(builder.data_dir)


@pytest.fixture(scope="module", params=sorted(SPECS))
def written(request, tmp_path_factory):
    return build(request.param, tmp_path_factory)


@pytest.fixture(scope="module")
def fractal(tmp_path_factory):
    return build("fractal20220817_data", tmp_path_factory)


def run(*args):
    done = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    return done.returncode, done.stdout, done.stderr


def episodes(root):
    config = tfds.ReadConfig(interleave_cycle_length=1)
    dataset = tfds.builder_from_directory(str(root)).as_dataset(split="train", shuffle_files=False, read_config=config)
    return [list(e["steps"].as_numpy_iterator()) for e in dataset]


def episode_values(root):
    """Each episode's values outside `steps`, by their path ("episode_metadata/file_path")."""
    config = tfds.ReadConfig(interleave_cycle_length=1)
    dataset = tfds.builder_from_directory(str(root)).as_dataset(split="train", shuffle_files=False, read_config=config)

    def flatten(tree, prefix=""):
        for key, value in tree.items():
            if isinstance(value, dict):
                yield from flatten(value, f"{prefix}{key}/")
            elif key != "steps":
                yield f"{prefix}{key}", value.numpy()

    return [dict(flatten(e)) for e in dataset]


def at(step, path):
    for part in path:
        step = step[part]
    return step


def flat(value):
    return np.asarray(value, np.float32).reshape(-1)


def expected_action(step, parts):
    if parts is None:
        return flat(step["action"])
    return np.concatenate([flat(step["action"][p]) for p in parts])


def expected_state(step, parts):
    return np.concatenate([flat(step["observation"][p]) for p in parts])


def text_of(step, where):
    value = at(step, where)
    if isinstance(value, bytes):
        return value.decode()
    return bytes(int(c) for c in value if c).decode()


def test_oxe_spec_converts_to_lerobot_without_loss(written, tmp_path):
    name, root = written
    _, _, where, action_parts, state_parts = SPECS[name]
    out = tmp_path / "lerobot"
    code, _, err = run("convert", root, "--to", "lerobot", "--fps", 10, "--out", out, "--verify")
    assert code == 0, err
    # Per-episode values travel as columns of the episodes table, named on stderr.
    field = {"language_table": "episode_id", "austin_buds_dataset_converted_externally_to_rlds": "episode_metadata/file_path"}.get(name)
    if field:
        assert f"{field}: per episode, carried as the LeRobot episodes table's column" in err, err
        episodes_table = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
        config = tfds.ReadConfig(interleave_cycle_length=1)
        stored = tfds.builder_from_directory(str(root)).as_dataset(split="train", shuffle_files=False, read_config=config)
        expected = [at(e, field.split("/")).numpy().decode() for e in stored]
        assert sorted(expected) == ["episode 0", "episode 1"], expected
        assert episodes_table[field] == expected, episodes_table.get(field)
    code, _, err = run("validate", out)
    assert code == 0, err
    # The card says where the data came from, with its own licence and citation, and invents
    # neither licence nor surgvla citation.
    card = (out / "README.md").read_text()
    assert f"the input is the RLDS dataset {name} 0.1.0, licence: CC-BY-4.0" in card, card
    assert f"@misc{{{name}, title={{{name}}}}}" in card and "license: apache-2.0" not in card, card
    # No provenance surgvla does not know: no seed, task id or success placeholders.
    columns = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").column_names
    assert not [c for c in columns if c.startswith("surgvla/")], columns
    info = json.loads((out / "meta/info.json").read_text())
    features = info["features"]
    table = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    tasks = pq.read_table(out / "meta/tasks.parquet").to_pydict()
    task_of = dict(zip(tasks["task_index"], tasks["task"]))
    if action_parts is not None:
        names = features["action"]["names"]
        assert len(names) == len(table["action"][0]), names
        assert names[0].startswith(action_parts[0]), names
    row = 0
    for steps in episodes(root):
        for step in steps:
            assert task_of[table["task_index"][row]] == text_of(step, where)
            assert np.array_equal(np.array(table["action"][row], np.float32), expected_action(step, action_parts))
            assert np.array_equal(np.array(table["observation.state"][row], np.float32), expected_state(step, state_parts))
            if name == "fractal20220817_data":  # carried under their own names
                assert table["action_terminate_episode"][row] == list(step["action"]["terminate_episode"])
                assert np.array_equal(np.array(table["observation.workspace_bounds"][row], np.float32), flat(step["observation"]["workspace_bounds"]))
            if name == "taco_play":
                assert table["observation.structured_language_instruction"][row] == step["observation"]["structured_language_instruction"].decode()
                assert np.array_equal(np.array(table["action_actions"][row], np.float32), step["action"]["actions"])
            row += 1
    assert row == len(table["index"]) == 7
    # For lerobot's own loader (tests/interop/oxe, run in the lerobot venv by .ci/run).
    if os.environ.get("SURGVLA_OXE_OUT"):
        shutil.copytree(out, Path(os.environ["SURGVLA_OXE_OUT"]) / name, dirs_exist_ok=True)


def test_oxe_spec_converts_to_rlds_tfds_reads(written, tmp_path):
    name, root = written
    _, _, where, action_parts, state_parts = SPECS[name]
    out = tmp_path / "rlds"
    code, _, err = run("convert", root, "--to", "rlds", "--fps", 10, "--out", out, "--verify")
    assert code == 0, err
    code, _, err = run("validate", out)
    assert code == 0, err
    version = next(out.glob("*/*"))
    again = episodes(version)
    original = episodes(root)
    # Per-episode values keep their paths and values (file_path: the input's where it has one).
    written_values, read_values = episode_values(version), episode_values(root)
    for x, y in zip(read_values, written_values):
        for key, value in x.items():
            assert np.array_equal(np.asarray(y[key]), np.asarray(value)), (key, y, x)
    # And through LeRobot's episodes table and back.
    lerobot, back = tmp_path / "lerobot", tmp_path / "back"
    for source, to, target in [(root, "lerobot", lerobot), (lerobot, "rlds", back)]:
        code, _, err = run("convert", source, "--to", to, "--fps", 10, "--out", target)
        assert code == 0, err
    code, _, err = run("validate", back)
    assert code == 0, err
    for x, y in zip(read_values, episode_values(next(back.glob("*/*")))):
        for key, value in x.items():
            assert np.array_equal(np.asarray(y[key]), np.asarray(value)), (key, y, x)
    # Every observation keeps its values and its shape (taco_play's 150 x 200 depth_static,
    # flattened on the way through LeRobot, declared with its shape again).
    for target in (version, next(back.glob("*/*"))):
        for a, b in zip(original, episodes(target)):
            for x, y in zip(a, b):
                for key, value in x["observation"].items():
                    if key == "instruction" or key in state_parts or isinstance(value, bytes):
                        continue  # the task, or joined into observation/state
                    assert key in y["observation"], (key, list(y["observation"]))
                    assert np.asarray(y["observation"][key]).shape == np.asarray(value).shape, key
                    assert np.array_equal(y["observation"][key], value), key
    assert [len(e) for e in again] == [len(e) for e in original]
    for a, b in zip(original, again):
        for x, y in zip(a, b):
            assert y["language_instruction"].decode() == text_of(x, where)
            assert np.array_equal(flat(y["action"]), expected_action(x, action_parts))
            assert np.array_equal(flat(y["observation"]["state"]), expected_state(x, state_parts))


def test_a_map_file_overrides_the_conventions(fractal, tmp_path):
    """`--map` on a tfds-written fractal dataset: the action is what the map names, in its
    order, with its names; what the map no longer takes is carried; a key the dataset lacks
    exits 2 listing its keys."""
    _, root = fractal
    mapping = tmp_path / "map.toml"
    mapping.write_text(
        '[[feature]]\nname = "action"\nkeys = ["action/rotation_delta", "action/world_vector"]\n'
        'names = ["rx", "ry", "rz", "x", "y", "z"]\n'
    )
    out = tmp_path / "lerobot"
    code, _, err = run("convert", root, "--to", "lerobot", "--fps", 10, "--map", mapping, "--out", out)
    assert code == 0, err
    assert "action = steps/action/rotation_delta + steps/action/world_vector" in err, err
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["action"]["names"] == ["rx", "ry", "rz", "x", "y", "z"]
    table = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    first = episodes(root)[0][0]
    expected = np.concatenate([first["action"]["rotation_delta"], first["action"]["world_vector"]])
    assert np.array_equal(np.array(table["action"][0], np.float32), expected)
    # What the map no longer takes is carried, not lost.
    carried = np.ravel(np.array(table["action_gripper_closedness_action"][0], np.float32))
    assert np.array_equal(carried, first["action"]["gripper_closedness_action"])
    mapping.write_text('[[feature]]\nname = "action"\nkeys = ["action/nothing"]\n')
    code, _, err = run("convert", root, "--to", "lerobot", "--fps", 10, "--map", mapping, "--out", tmp_path / "bad")
    assert code == 2 and "steps/action/world_vector" in err, err


def test_depth_and_jpeg_keep_what_they_are_through_lerobot_and_back(tmp_path_factory, tmp_path):
    """A 16-bit depth image (tfds Image of uint16, as OXE datasets store depth) and a JPEG
    camera: through LeRobot (the depth says `is_depth_map`, both keep their bytes) and back to
    RLDS, whose features.json declares them as they are (uint16 PNG, JPEG), so tfds decodes
    the same pixels as from the dataset it wrote."""
    spec = (
        {
            "action": tensor(7), "reward": scalar(), "language_instruction": TEXT,
            "observation": {
                "image": tfds.features.Image(shape=(48, 64, 3), encoding_format="jpeg"),
                "depth": tfds.features.Image(shape=(48, 64, 1), dtype=np.uint16),
                "state": tensor(7),
            },
        },
        {}, ("language_instruction",), None, ["state"],
    )
    SPECS["depth_and_jpeg"] = spec
    try:
        _, root = build("depth_and_jpeg", tmp_path_factory)
    finally:
        del SPECS["depth_and_jpeg"]
    lerobot, rlds = tmp_path / "lerobot", tmp_path / "rlds"
    for source, to, target in [(root, "lerobot", lerobot), (lerobot, "rlds", rlds)]:
        code, _, err = run("convert", source, "--to", to, "--fps", 10, "--out", target, "--verify")
        assert code == 0, err
        code, _, err = run("validate", target)
        assert code == 0, err
    info = json.loads((lerobot / "meta/info.json").read_text())
    assert info["features"]["observation.images.depth"]["info"]["is_depth_map"] is True, info
    # The JPEG camera re-encodes to video (decoded as the JPEG it is), the depth map kept.
    video = tmp_path / "video"
    code, _, err = run("convert", lerobot, "--to", "lerobot", "--video", "av1", "--out", video, "--verify")
    assert code == 0, err
    code, _, err = run("validate", video)
    assert code == 0, err
    features = json.loads((video / "meta/info.json").read_text())["features"]
    assert features["observation.images.image"]["dtype"] == "video", features
    assert features["observation.images.depth"]["dtype"] == "image", features
    version = next(rlds.glob("*/*"))
    features = json.loads((version / "features.json").read_text())
    observation = features["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"]["features"]["observation"]["featuresDict"]["features"]
    assert observation["image"]["image"]["encodingFormat"] == "jpeg", observation["image"]
    assert observation["depth"]["image"]["dtype"] == "uint16", observation["depth"]
    for a, b in zip(episodes(root), episodes(version)):
        for x, y in zip(a, b):
            assert np.array_equal(x["observation"]["depth"], y["observation"]["depth"])
            assert x["observation"]["depth"].dtype == y["observation"]["depth"].dtype == np.uint16
            assert np.array_equal(x["observation"]["image"], y["observation"]["image"])


# maniskill's depth: "divide the depth value by 2**10 to get the depth in meters".
DEPTH_UNIT_M = 2.0**-10
INTRINSICS = (128.0, 128.0, 128.0, 128.0)
CROP = (-100.0, -100.0, 0.0, 100.0, 100.0, 100.0)
ROLES = [
    "--camera", "observation.images.image", "--depth", "observation.images.depth",
    "--depth-unit-m", repr(DEPTH_UNIT_M), "--intrinsics", ",".join(map(str, INTRINSICS)),
    "--crop=" + ",".join(map(str, CROP)),
]


def test_a_named_camera_and_depth_make_zarr_mcap_and_point_clouds(tmp_path_factory, tmp_path):
    """The held-out maniskill spec (uint16 depth images in 1/1024 m, a wrist camera, camera
    matrices per step) into zarr, MCAP, PLY and PCD, which are built around one camera: without
    --camera each refuses naming the flag and the dataset's image features, writing nothing;
    with --camera/--depth/--depth-unit-m/--intrinsics/--crop each is written, says on stderr
    what it leaves out, and validates. The outputs and the values they must hold go to
    SURGVLA_ROLES_OUT for the real readers (tests/interop/clouds: zarr 3, plyfile, Open3D;
    tests/interop/mcap: the mcap reader)."""
    name, root = build("maniskill_dataset_converted_externally_to_rlds", tmp_path_factory)
    out = Path(os.environ.get("SURGVLA_ROLES_OUT") or tmp_path / "roles")
    out.mkdir(parents=True, exist_ok=True)
    for to in ["zarr", "mcap", "ply", "pcd"]:
        target = out / to
        shutil.rmtree(target, ignore_errors=True)
        code, _, err = run("convert", root, "--to", to, "--fps", 10, "--out", target)
        assert code == 2 and "--camera KEY" in err and "observation.images.wrist_image" in err, err
        assert not target.exists()
        code, _, err = run("convert", root, "--to", to, "--fps", 10, *ROLES, "--out", target, "--verify")
        assert code == 0, err
        assert "the camera is observation.images.image (256x256)" in err, err
        assert f"{DEPTH_UNIT_M} m (--depth-unit-m)" in err, err
        left_out = [line for line in err.splitlines() if ": left out " in line]
        if to == "mcap":
            assert not left_out, err
        else:  # zarr keeps the vectors, point clouds nothing else; one line names them
            assert len(left_out) == 1 and "observation.images.wrist_image" in left_out[0], err
            assert ("observation.state" in left_out[0]) == (to != "zarr"), err
        code, _, err = run("validate", target)
        assert code == 0, err
    # What the readers compare with, read by tfds: values, and the wrist camera's PNG bytes as
    # stored (SkipDecoding), which MCAP carries unchanged.
    config = tfds.ReadConfig(interleave_cycle_length=1)
    builder = tfds.builder_from_directory(str(root))
    stored = builder.as_dataset(
        split="train", shuffle_files=False, read_config=config,
        decoders={"steps": {"observation": {"wrist_image": tfds.decode.SkipDecoding()}}},
    )
    steps = [s for e in stored for s in e["steps"].as_numpy_iterator()]
    decoded = [s for e in episodes(root) for s in e]
    lengths = [len(e) for e in episodes(root)]
    np.savez(
        out / "expected.npz",
        action=np.stack([s["action"] for s in decoded]),
        state=np.stack([s["observation"]["state"] for s in decoded]),
        base_pose=np.stack([s["observation"]["base_pose"] for s in decoded]),
        image=np.stack([s["observation"]["image"] for s in decoded]),
        depth_m=np.stack([(s["observation"]["depth"][:, :, 0] * DEPTH_UNIT_M).astype(np.float32) for s in decoded]),
        episode_ends=np.cumsum(lengths),
    )
    expected = {
        "intrinsics": INTRINSICS,
        "lengths": lengths,
        "action": [s["action"].tolist() for s in decoded],
        "wrist_png_sha256": [__import__("hashlib").sha256(s["observation"]["wrist_image"]).hexdigest() for s in steps],
        "depth_m_sha256": [__import__("hashlib").sha256((s["observation"]["depth"][:, :, 0] * DEPTH_UNIT_M).astype("<f4").tobytes()).hexdigest() for s in decoded],
        "instructions": [s["language_instruction"].decode() for s in decoded],
    }
    (out / "expected.json").write_text(json.dumps(expected))


# Each spec's camera, as surgvla names the key (observation/<camera> -> observation.images.<camera>).
CAMERA = {
    "fractal20220817_data": "image", "bridge": "image", "taco_play": "rgb_static", "jaco_play": "image",
    "language_table": "rgb", "austin_buds_dataset_converted_externally_to_rlds": "image",
    "maniskill_dataset_converted_externally_to_rlds": "image",
}


def test_oxe_spec_converts_to_zarr_and_mcap_with_its_camera(written, tmp_path):
    """Every spec into zarr and MCAP with `--camera` naming its camera: each validates, and the
    outputs with the values they must hold (the action, the camera's frames as tfds decodes
    them) go to SURGVLA_ROLES_OUT/specs/<name> for the real readers (zarr 3 in
    tests/interop/clouds, the mcap reader in tests/interop/mcap)."""
    name, root = written
    _, _, _, action_parts, _ = SPECS[name]
    out = Path(os.environ.get("SURGVLA_ROLES_OUT") or tmp_path / "roles") / "specs" / name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    camera = f"observation.images.{CAMERA[name]}"
    for to in ["zarr", "mcap"]:
        code, _, err = run("convert", root, "--to", to, "--fps", 10, "--camera", camera, "--out", out / to)
        assert code == 0, err
        code, _, err = run("validate", out / to)
        assert code == 0, err
    steps = [s for e in episodes(root) for s in e]
    actions = np.stack([expected_action(s, action_parts) for s in steps])
    np.savez(out / "expected.npz", action=actions, image=np.stack([s["observation"][CAMERA[name]] for s in steps]))
    lengths = [len(e) for e in episodes(root)]
    (out / "expected.json").write_text(json.dumps({"action": actions.tolist(), "lengths": lengths}))
