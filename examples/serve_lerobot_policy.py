#!/usr/bin/env python3
"""Serve a LeRobot policy over openpi's policy-server protocol, so `surgvla eval` can score it.

    # beside lerobot 0.6.1 (Python 3.12): pip install --no-deps -r examples/requirements-serve.txt
    python examples/serve_lerobot_policy.py --policy-path outputs/train/act/checkpoints/last/pretrained_model --port 8000
    surgvla eval --policy ws://localhost:8000 --replan-steps 10 --out eval-act

The protocol is openpi's (`serve_policy.py`; `examples/policy_server.py` serves it): on connecting, the client gets one metadata
message; then every binary message it sends (msgpack-numpy, `openpi_client.msgpack_numpy`)
is an observation

    {"observation/image": uint8 (224, 224, 3), "observation/state": float32 (7,), "prompt": str,
     and, when `surgvla eval --send ...` asks, "observation/depth": float32 (224, 224) metres,
     "observation/environment_state": float32 (28,)}

and gets one reply {"actions": float32 (H, 7)}: the policy's whole action chunk (ACT's
`chunk_size`), unnormalised into dataset actions (deltas + gripper 1 open / 0 closed); the
client decides how many to execute (`--replan-steps`). An exception is sent back as text (the
traceback), then the connection closes, as openpi's server does; `surgvla eval` fails that trial
with the text and reconnects for the next.

The policy is stateless between requests (`predict_action_chunk`), so trials need no reset
message. Its inputs are taken by name from the observation: image features get the endoscope
image, `observation.state` the state, `observation.environment_state` the object poses.
"""

import argparse
import asyncio
import logging

import numpy as np
import torch
from policy_server import serve  # examples/policy_server.py: the protocol, for any policy

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.policies.factory import get_policy_class, make_pre_post_processors


class LeRobotPolicy:
    """A LeRobot `PreTrainedPolicy` with its saved pre- and post-processors."""

    def __init__(self, path: str, device: str):
        config = PreTrainedConfig.from_pretrained(path)
        config.device = device
        self.config = config
        self.policy = get_policy_class(config.type).from_pretrained(path, config=config)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            config,
            pretrained_path=path,
            preprocessor_overrides={"device_processor": {"device": device}},
        )
        self.device = device

    def metadata(self) -> dict:
        return {
            "server": "surgvla examples/serve_lerobot_policy.py",
            "policy_type": self.config.type,
            "input_features": {k: list(f.shape) for k, f in self.config.input_features.items()},
            "output_features": {k: list(f.shape) for k, f in self.config.output_features.items()},
        }

    def _input(self, key: str, feature, observation: dict) -> torch.Tensor:
        if feature.type is FeatureType.VISUAL:
            if "depth" in key:
                depth = np.asarray(observation["observation/depth"], dtype=np.float32)
                return torch.from_numpy(depth.copy())[None]
            image = np.asarray(observation["observation/image"], dtype=np.uint8)
            return torch.from_numpy(image.copy()).permute(2, 0, 1).float() / 255.0
        if key == "observation.state":
            return torch.from_numpy(np.asarray(observation["observation/state"], dtype=np.float32).copy())
        if key == "observation.environment_state":
            values = observation.get("observation/environment_state")
            if values is None:
                raise KeyError(
                    "the policy needs observation.environment_state: run surgvla eval with --send environment_state"
                )
            return torch.from_numpy(np.asarray(values, dtype=np.float32).copy())
        raise KeyError(f"the policy needs {key}, which surgvla eval does not send")

    @torch.inference_mode()
    def infer(self, observation: dict) -> dict:
        batch = {
            key: self._input(key, feature, observation).unsqueeze(0).to(self.device)
            for key, feature in self.config.input_features.items()
        }
        batch["task"] = str(observation.get("prompt", ""))
        batch["robot_type"] = "dvrk_psm"
        batch = self.preprocessor(batch)
        chunk = self.policy.predict_action_chunk(batch)  # (1, H, action_dim)
        chunk = self.postprocessor(chunk)
        actions = chunk[0].detach().cpu().numpy().astype(np.float32)
        return {"actions": actions.reshape(-1, actions.shape[-1])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy-path", required=True, help="a pretrained_model folder lerobot-train saved")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000, help="0 picks a free port (printed)")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    policy = LeRobotPolicy(args.policy_path, args.device)
    asyncio.run(serve(policy, args.host, args.port, name=policy.config.type))


if __name__ == "__main__":
    main()
