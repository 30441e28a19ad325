//! `OPENVLA.md`, written beside an RLDS dataset: the dataset-registry entry and standardize
//! transform a user pastes into OpenVLA (`prismatic/vla/datasets/rlds/oxe/configs.py` and
//! `transforms.py`), the fine-tuning command and the normalisation to expect. The interop test
//! executes its Python blocks on the dataset with `tf.data`.

use crate::episode::{FeatureKind, GripperEncoding};
use crate::export::info::DatasetInfo;
use crate::export::rlds::options::RldsOptions;

/// The guide's paragraph on depth (empty without it).
fn depth_note(info: &DatasetInfo, options: &RldsOptions) -> String {
    let keys = &options.keys;
    if info.has(FeatureKind::Depth) {
        format!(
            "\n`steps/observation/{}` holds depth as 1-channel uint16 PNG in millimetres along the optical \
             axis (0 = nothing in range). Read through `tfds` itself it arrives as those uint16 values: \
             divide by 1000 for metres. OpenVLA does not use depth; Octo-style pipelines (set \
             `depth_obs_keys` to `{{\"primary\": \"{}\"}}`) decode it with `decode_and_resize`, which \
             scales a uint16 image to 0..1 (value / 65535): there multiply by 65.535 for metres \
             (65535 / 1000).\n",
            keys.depth, keys.depth
        )
    } else {
        String::new()
    }
}

/// How the guide describes the gripper and rebuilds what OpenVLA expects from it: (the
/// action's last element, the transform's lines for it, the normalisation's sentence).
fn gripper_text(info: &DatasetInfo) -> (&'static str, &'static str, &'static str) {
    let pulse = info
        .collection
        .as_ref()
        .and_then(|c| c.gripper_encoding())
        .is_some_and(|e| e == GripperEncoding::Pulse);
    if pulse {
        (
            "the gripper as a **pulse**: +1 on the step the jaws are commanded open, -1 on the \
             step they are commanded closed, 0 otherwise (the jaws start open; `collect \
             --gripper-encoding pulse`)",
            r#"    # The gripper is a pulse (+1 commanded open, -1 commanded closed, 0 otherwise; the
    # jaws start open): rebuild OpenVLA's absolute gripper, 1 = open, 0 = closed.
    pulse = trajectory["action"][:, -1]
    gripper = tf.scan(
        lambda held, p: tf.where(p > 0.5, 1.0, tf.where(p < -0.5, 0.0, held)),
        pulse,
        initializer=tf.constant(1.0, pulse.dtype),
    )
    trajectory["action"] = tf.concat([trajectory["action"][:, :6], gripper[:, None]], axis=-1)
"#,
            "The transform above turns the pulse into that absolute gripper: without it \
             OpenVLA would read -1/0/+1 as gripper states. ",
        )
    } else {
        (
            "the gripper, absolute, **1 = open, 0 = closed**",
            "    # The action already is OpenVLA's EEF_POS: six end-effector deltas and an absolute\n    \
             # gripper with 1 = open, 0 = closed.\n",
            "",
        )
    }
}

/// The guide for a dataset of `info` written with `options`.
pub fn openvla_md(info: &DatasetInfo, options: &RldsOptions, split: &str) -> String {
    let name = &options.name;
    let keys = &options.keys;
    let (gripper, gripper_transform, gripper_note) = gripper_text(info);
    let state_names = info
        .feature(FeatureKind::State)
        .map(|f| f.names.join(", "))
        .unwrap_or_default();
    let depth = depth_note(info, options);
    format!(
        r#"# Fine-tuning OpenVLA on `{name}`

This folder is a TFDS data directory: `{name}/{version}/` holds RLDS (one episode per
`tf.train.Example`, written by {generator} without TensorFlow). Load it with

```text
tfds.builder("{name}", data_dir="<this folder>")
tfds.builder_from_directory("<this folder>/{name}/{version}")
```

Each step: `observation/{image}` (224 x 224 x 3 uint8 PNG, the endoscope),
`observation/{state}` (float32 x 7: {state_names}), `action` (float32 x 7: dx, dy, dz in
metres, droll, dpitch, dyaw in radians per control step at {fps} Hz, and {gripper}),
`language_instruction`, `is_first`, `is_last`, `is_terminal`,
`reward` (1.0 on the last step of a successful episode) and `discount`.
`episode_metadata/` holds `file_path` (task id and seed), `task_id`, `level`, `seed`, `success`.
{depth}
## 1. Register the dataset

Append to `prismatic/vla/datasets/rlds/oxe/configs.py` (after `OXE_DATASET_CONFIGS`):

```python
OXE_DATASET_CONFIGS["{name}"] = {{
    "image_obs_keys": {{"primary": "{image}", "secondary": None, "wrist": None}},
    "depth_obs_keys": {{"primary": None, "secondary": None, "wrist": None}},
    "state_obs_keys": ["EEF_state", None, "gripper_state"],
    "state_encoding": StateEncoding.POS_EULER,
    "action_encoding": ActionEncoding.EEF_POS,
}}
```

## 2. The standardize transform

Append to `prismatic/vla/datasets/rlds/oxe/transforms.py` (after
`OXE_STANDARDIZATION_TRANSFORMS`):

```python
def {name}_dataset_transform(trajectory: Dict[str, Any]) -> Dict[str, Any]:
{gripper_transform}    # The state is split into the end effector and the gripper.
    state = trajectory["observation"]["{state}"]
    trajectory["observation"]["EEF_state"] = state[:, :6]
    trajectory["observation"]["gripper_state"] = state[:, -1:]
    return trajectory


OXE_STANDARDIZATION_TRANSFORMS["{name}"] = {name}_dataset_transform
```

## 3. Fine-tune

```text
torchrun --standalone --nnodes 1 --nproc-per-node 1 vla-scripts/finetune.py \
  --vla_path "openvla/openvla-7b" \
  --data_root_dir <this folder> \
  --dataset_name {name} \
  --run_root_dir <checkpoints> --adapter_tmp_dir <adapters> \
  --lora_rank 32 --batch_size 16 --grad_accumulation_steps 1 --learning_rate 5e-4 \
  --image_aug True --save_steps 5000
```

## Normalisation to expect

OpenVLA computes the dataset's statistics on first load (cached in its data directory) and
normalises with `BOUNDS_Q99`: each of the six deltas is mapped from its [1st, 99th] percentile
to [-1, 1] and clipped. The gripper is absolute (`absolute_action_mask = [False] * 6 + [True]`)
and is not normalised (`action_normalization_mask = [True] * 6 + [False]`): it stays 1 = open,
0 = closed, which is what the policy must output. {gripper_note}The deltas are small (millimetres per step),
so the percentiles, not the units, decide their scale. The state's last element is the jaw
angle in radians, not 0/1. {splits}
"#,
        splits = split_note(split),
        version = options.version,
        generator = info.generator,
        image = keys.image,
        state = keys.state,
        fps = info.fps,
    )
}

/// What the guide says of the dataset's one TFDS split ([`super::options::tfds_split`]).
fn split_note(split: &str) -> String {
    if split == "train" {
        "There is one `train` split; OpenVLA trains on `train[:95%]` and\nvalidates on \
         `train[95%:]`."
            .into()
    } else {
        format!(
            "There is one split, `{split}` (`surgvla edit --split` writes one dataset per \
             split): OpenVLA fine-tunes on a split named `train`, so fine-tune on the dataset \
             holding `train` and read this one with `as_dataset(split=\"{split}\")`."
        )
    }
}

/// The card's loading snippet: `tensorflow_datasets` on the version folder, reading `split`.
pub(super) fn loading_snippet(options: &RldsOptions, split: &str) -> String {
    format!(
        "With tensorflow_datasets, from this folder (OPENVLA.md shows how to fine-tune OpenVLA on it):\n\n```python\nimport tensorflow_datasets as tfds\n\nbuilder = tfds.builder_from_directory(\"{name}/{version}\")\nfor episode in builder.as_dataset(split=\"{split}\").take(1):\n    for step in episode[\"steps\"]:\n        image, action = step[\"observation\"][\"{image}\"], step[\"action\"]\n```\n",
        name = options.name,
        version = options.version,
        image = options.keys.image,
    )
}
