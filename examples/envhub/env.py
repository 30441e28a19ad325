"""surgvla's eight laparoscopic tasks as a LeRobot EnvHub environment.

Upload this file as `env.py` to a Hugging Face Hub repository (e.g. `you/surgvla`); with the
surgvla wheel installed (docs/python.md), lerobot builds the environments from it:

    from lerobot.envs.factory import make_env
    envs = make_env("you/surgvla", n_envs=10, trust_remote_code=True)
    # {"surgvla": {"T1-1": vector env, ..., "T3-2": vector env}}

and `lerobot.scripts.lerobot_eval.eval_policy` scores a policy on each (docs/eval.md).
"""

from surgvla.lerobot import make_env  # noqa: F401
