#!/usr/bin/env python3
"""Gymnasium's environment steps per second, the counterpart of `mbpo bench env`.

    .venv/bin/python tools/gym_env_speed.py [--seconds 2] [--env HalfCheetah-v5 ...]

One JSON line per environment, {"bench": "env", "impl": "gymnasium", "env": ..., "steps_per_sec":
...}, measured like the Rust benchmark: one thread, 4096 pre-drawn uniform actions cycled,
`env.step` through `gym.make`'s wrappers (the way an agent calls it), reset at episode end.
`deploy/bench_envs.sh` runs both benchmarks back to back.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import gymnasium as gym
import numpy as np

IDS = ["Pendulum-v1", "MountainCarContinuous-v0", "InvertedPendulum-v5", "HalfCheetah-v5",
       "Hopper-v5", "Walker2d-v5", "Ant-v5"]
MAKE_KWARGS = {"Ant-v5": {"include_cfrc_ext_in_observation": False}}


def steps_per_sec(env_id: str, seconds: float) -> tuple[float, int]:
    env = gym.make(env_id, **MAKE_KWARGS.get(env_id, {}))
    rng = np.random.default_rng(0)
    low, high = env.action_space.low, env.action_space.high
    actions = rng.uniform(low, high, size=(4096, low.size)).astype(np.float32)
    env.reset(seed=0)
    steps = episodes = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
                episodes += 1
        steps += len(actions)
    return steps / (time.perf_counter() - start), episodes


def main() -> None:
    warnings.filterwarnings("ignore")
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--env", action="append", help="environment id (repeatable; default: all)")
    args = p.parse_args()
    for env_id in args.env or IDS:
        sps, episodes = steps_per_sec(env_id, args.seconds)
        print(json.dumps({"bench": "env", "impl": "gymnasium", "env": env_id,
                          "steps_per_sec": round(sps), "episodes": episodes, "threads": 1}),
              flush=True)


if __name__ == "__main__":
    main()
