"""`surgvla edit` on an RLDS dataset, read by the real tensorflow_datasets.

.ci/run gives SURGVLA_RLDS_DATASET (`collect --format rlds --rlds-shard-mb 1`: 6 episodes over
several shards) and SURGVLA_BIN. Both sides are read through tensorflow_datasets only.
"""

import os
import subprocess
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import tensorflow_datasets as tfds  # noqa: E402

RLDS = Path(os.environ.get("SURGVLA_RLDS_DATASET", "")).resolve()
BIN = os.environ.get("SURGVLA_BIN", "surgvla")
NAME, VERSION = "surgvla_benchmark", "1.0.0"


def edit(tmp_path, *args):
    out = tmp_path / "out"
    done = subprocess.run([BIN, "edit", str(RLDS), *args, "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return out


def actions(root, split):
    """Each episode's actions, in order, as tfds reads `split` of the dataset at `root`."""
    builder = tfds.builder_from_directory(str(root / NAME / VERSION))
    in_order = tfds.ReadConfig(interleave_cycle_length=1)
    episodes = builder.as_dataset(split=split, shuffle_files=False, read_config=in_order)
    found = [np.stack([s["action"] for s in e["steps"].as_numpy_iterator()]) for e in episodes]
    assert builder.info.splits[split].num_examples == len(found)
    return found


def index_of(episode, among):
    matches = [i for i, other in enumerate(among) if other.shape == episode.shape and np.array_equal(other, episode)]
    assert len(matches) == 1, f"{len(matches)} input episodes match"
    return matches[0]


def test_a_drop_keeps_the_other_episodes_in_order(tmp_path):
    original = actions(RLDS, "train")
    out = edit(tmp_path, "--drop", "0,3")
    kept = actions(out, "train")
    assert [index_of(e, original) for e in kept] == [1, 2, 4, 5]


def test_each_split_is_a_dataset_read_under_its_own_split_name(tmp_path):
    original = actions(RLDS, "train")
    out = edit(tmp_path, "--split", "train=0.5,val=0.5")
    seen = []
    for split in ["train", "val"]:
        builder = tfds.builder_from_directory(str(out / split / NAME / VERSION))
        assert list(builder.info.splits.keys()) == [split]
        episodes = actions(out / split, split)
        assert len(episodes) == 3, split
        seen += [index_of(e, original) for e in episodes]
    assert sorted(seen) == list(range(len(original)))


def test_a_split_datasets_card_snippet_reads_its_own_split(tmp_path, monkeypatch):
    """The "Loading" code block of the `val` dataset's card, run from its folder as written."""
    out = edit(tmp_path, "--split", "train=0.5,val=0.5")
    card = (out / "val" / "README.md").read_text()
    snippet = card.split("## Loading", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    assert 'split="val"' in snippet
    monkeypatch.chdir(out / "val")
    scope = {}
    exec(snippet, scope)
    assert tuple(scope["image"].shape) == (224, 224, 3)
    assert tuple(scope["action"].shape) == (7,)
