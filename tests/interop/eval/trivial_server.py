"""A trivial policy behind openpi's policy-server protocol (examples/policy_server.py, on
openpi-client's own msgpack-numpy encoding, as openpi's `WebsocketPolicyServer` serves one: the
metadata message on connect, then one binary reply per binary request; an exception goes back
as text, the traceback, before the connection closes).

The policy checks what it is sent (keys, dtypes, shapes, a non-empty prompt) and answers a chunk
of `--chunk` actions: `zeros` (zero deltas, jaws open) or `square` (a small square in x-y, the
jaws open). Every observation is described in the JSON-lines `--log`.

    python trivial_server.py --port 0 --policy zeros --chunk 8 --log seen.jsonl
"""

import argparse
import asyncio
import json
import sys
from pathlib import Path

import numpy as np

# The protocol's server side, shared with examples/serve_lerobot_policy.py.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "examples"))
from policy_server import serve  # noqa: E402

EXPECTED = {
    "observation/image": (np.uint8, (224, 224, 3)),
    "observation/state": (np.float32, (7,)),
    "observation/depth": (np.float32, (224, 224)),
    "observation/environment_state": (np.float32, (28,)),
}


class Policy:
    def __init__(self, kind: str, chunk: int, log: str):
        self.kind, self.chunk, self.log = kind, chunk, log
        self.requests = 0

    def metadata(self) -> dict:
        return {"policy": self.kind, "chunk": self.chunk}

    def infer(self, observation: dict) -> dict:
        described = {}
        for key, value in observation.items():
            if key == "prompt":
                if not isinstance(value, str) or not value:
                    raise ValueError(f"prompt is {value!r}")
                described[key] = value
                continue
            dtype, shape = EXPECTED[key]  # KeyError for anything unexpected
            if not isinstance(value, np.ndarray) or value.dtype != dtype or value.shape != shape:
                raise ValueError(f"{key}: {type(value)} {getattr(value, 'dtype', None)} {getattr(value, 'shape', None)}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{key} is not finite")
            described[key] = [str(value.dtype), list(value.shape), float(value.astype(np.float64).mean())]
        for key in ("observation/image", "observation/state", "prompt"):
            if key not in observation:
                raise KeyError(key)
        with open(self.log, "a") as log:
            log.write(json.dumps(described) + "\n")
        self.requests += 1
        actions = np.zeros((self.chunk, 7), dtype=np.float32)
        actions[:, 6] = 1.0
        if self.kind == "square":
            for i in range(self.chunk):
                side = (self.requests * self.chunk + i) // 10 % 4
                actions[i, 0:2] = [(0.001, 0), (0, 0.001), (-0.001, 0), (0, -0.001)][side]
        return {"actions": actions}


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--policy", choices=["zeros", "square"], default="zeros")
    parser.add_argument("--chunk", type=int, default=8)
    parser.add_argument("--log", required=True)
    args = parser.parse_args()
    asyncio.run(serve(Policy(args.policy, args.chunk, args.log), "127.0.0.1", args.port))
