#!/usr/bin/env python3
"""Write Gymnasium v5 MuJoCo reference trajectories as JSON fixtures for the Rust MuJoCo tasks.

Regenerate (from the repository root):

    bash deploy/setup_mujoco.sh && .venv/bin/python tools/gym_mujoco_reference.py

This writes common/envs/tests/fixtures/<EnvId>.json for InvertedPendulum-v5, HalfCheetah-v5,
Hopper-v5, Walker2d-v5, Ant-v5 and Humanoid-v5 (the last two with MBPO's truncated observations:
see MAKE_KWARGS), which common/envs/tests/gymnasium_mujoco.rs replays with `reset_to` + `step`
(cargo feature `mujoco`). Versions are pinned in tools/requirements*.txt and recorded in every
fixture.

Fixture format (as tools/gym_reference.py, plus the MuJoCo version):

    {"env_id": str, "gymnasium_version": str, "numpy_version": str, "mujoco_version": str,
     "make_kwargs": {...},
     "episodes": [{"name": str,
                   "state": [f64, ...],        # qpos followed by qvel at the start
                   "actions": [[f32, ...], ...],
                   "obs": [[f64, ...], ...],   # obs[0]: at the start; then one per step
                   "rewards": [f64, ...],
                   "terminated": [bool, ...],
                   "truncated": [bool, ...]}]}

How an episode is run: `gym.make(id, **make_kwargs)` (TimeLimit reports `truncated` at 1000
steps), `env.reset(seed=...)`; for a given start state, MuJoCo's data is reset again
(`mj_resetData`, as Gymnasium's own reset does) and `set_state(qpos, qvel)` applied. Actions are
float32 arrays. An episode stops at `terminated`, `truncated` or after `max_steps` (to keep the
fixtures small). Floats are written with `repr`, which round-trips exactly.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

REPO = Path(__file__).resolve().parent.parent
FIXTURES = REPO / "common" / "envs" / "tests" / "fixtures"


def run_episode(env_id, kwargs, name, seed, policy, state=None, max_steps=1000):
    """One episode from the seeded reset state, or from `state` (qpos then qvel) when given.

    `policy(t, obs, rng, low, high)` returns the action (converted to float32 here).
    """
    env = gym.make(env_id, **kwargs)
    obs, _ = env.reset(seed=seed)
    u = env.unwrapped
    nq = u.model.nq
    if state is not None:
        state = np.asarray(state, dtype=np.float64)
        mujoco.mj_resetData(u.model, u.data)
        u.set_state(state[:nq], state[nq:])
        obs = u._get_obs()
    start = np.concatenate([u.data.qpos, u.data.qvel])
    low, high = env.action_space.low, env.action_space.high
    rng = np.random.default_rng(seed + 1000)
    ep = {
        "name": name,
        "state": [float(x) for x in start],
        "actions": [],
        "obs": [[float(x) for x in obs]],
        "rewards": [],
        "terminated": [],
        "truncated": [],
    }
    for t in range(max_steps):
        action = np.asarray(policy(t, obs, rng, low, high), dtype=np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        assert obs.dtype == np.float64, obs.dtype
        ep["actions"].append([float(x) for x in action])
        ep["obs"].append([float(x) for x in obs])
        ep["rewards"].append(float(reward))
        ep["terminated"].append(bool(terminated))
        ep["truncated"].append(bool(truncated))
        if terminated or truncated:
            break
    env.close()
    return ep


def uniform(scale=1.0):
    """Uniform actions over the action box widened by `scale` (> 1: MuJoCo clamps the control)."""
    return lambda t, obs, rng, low, high: rng.uniform(low * scale, high * scale)


def bang_bang(t, obs, rng, low, high):
    """Each actuator at -1.5x, its bounds, 0 or 1.5x (exact bounds and clamped values)."""
    choices = np.stack([1.5 * low, low, np.zeros_like(low), high, 1.5 * high])
    return choices[rng.integers(5, size=low.shape), np.arange(low.size)]


def balance(t, obs, rng, low, high):
    """A PD controller that keeps the inverted pendulum up (slider x, angle th), plus noise."""
    x, th, v, w = obs
    return np.clip([1.0 * x + 10.0 * th + 0.5 * v + 1.5 * w + rng.normal(0, 0.05)], low, high)


def episodes(env_id):
    if env_id == "InvertedPendulum-v5":
        return [
            ("reset_seed0_uniform", 0, uniform(), None, 1000),
            ("reset_seed1_wide", 1, uniform(1.5), None, 1000),
            ("reset_seed2_bang_bang", 2, bang_bang, None, 1000),
            ("balanced_to_time_limit", 3, balance, None, 1000),
            ("start_near_angle_limit", 4, uniform(0.3), [0.1, 0.19, 0.0, 0.3], 1000),
        ]
    if env_id == "HalfCheetah-v5":
        return [
            ("reset_seed0_uniform_full_episode", 0, uniform(), None, 1000),
            ("reset_seed1_wide", 1, uniform(1.5), None, 200),
            ("reset_seed2_bang_bang", 2, bang_bang, None, 200),
            ("flipped_start", 3, uniform(), [0.5, 0.2, 2.8] + [0.3] * 6 + [1.0] * 9, 150),
        ]
    if env_id == "Hopper-v5":
        return [
            ("reset_seed0_uniform", 0, uniform(), None, 1000),
            ("reset_seed1_uniform", 1, uniform(), None, 1000),
            ("reset_seed2_wide", 2, uniform(1.5), None, 1000),
            ("reset_seed3_bang_bang", 3, bang_bang, None, 1000),
            ("reset_seed4_zero_action", 4, lambda *a: np.zeros(3), None, 1000),
            # A joint velocity far outside (-100, 100): unhealthy state on the first step.
            ("velocity_out_of_range", 5, uniform(), [0, 1.25, 0, 0, 0, 0, 0, 0, 0, 150.0, 0, 0], 1000),
        ]
    if env_id == "Walker2d-v5":
        return [
            ("reset_seed0_uniform", 0, uniform(), None, 1000),
            ("reset_seed1_wide", 1, uniform(1.5), None, 1000),
            ("reset_seed2_bang_bang", 2, bang_bang, None, 1000),
            ("reset_seed3_zero_action", 3, lambda *a: np.zeros(6), None, 1000),
            # Torso angle starting beyond 1 rad: terminated on the first step.
            ("leaning_start", 4, uniform(), [0, 1.25, 1.05] + [0] * 6 + [0] * 9, 1000),
        ]
    if env_id == "Ant-v5":
        return [
            ("reset_seed0_uniform", 0, uniform(), None, 300),
            ("reset_seed1_wide", 1, uniform(1.5), None, 200),
            ("reset_seed2_bang_bang", 2, bang_bang, None, 200),
            # Dropped from z = 1.3 (> 1, unhealthy): terminated on the first step.
            ("dropped_from_high", 3, uniform(), [0, 0, 1.3, 1, 0, 0, 0] + [0] * 8 + [0] * 14, 1000),
        ]
    if env_id == "Humanoid-v5":
        return [
            ("reset_seed0_uniform", 0, uniform(), None, 300),
            ("reset_seed1_wide", 1, uniform(1.5), None, 200),
            ("reset_seed2_bang_bang", 2, bang_bang, None, 200),
            ("reset_seed3_zero_action", 3, lambda *a: np.zeros(17), None, 300),
            # Dropped from z = 2.2 (> 2, unhealthy): terminated on the first step.
            ("dropped_from_high", 4, uniform(), [0, 0, 2.2, 1, 0, 0, 0] + [0] * 17 + [0] * 23, 1000),
        ]
    raise ValueError(env_id)


MAKE_KWARGS = {
    "Ant-v5": {"include_cfrc_ext_in_observation": False},
    # MBPO's HumanoidTruncatedObs: positions without the root's x and y, then velocities.
    "Humanoid-v5": {
        "include_cinert_in_observation": False,
        "include_cvel_in_observation": False,
        "include_qfrc_actuator_in_observation": False,
        "include_cfrc_ext_in_observation": False,
    },
}


def main() -> None:
    warnings.filterwarnings("ignore")
    FIXTURES.mkdir(parents=True, exist_ok=True)
    for env_id in ["InvertedPendulum-v5", "HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Ant-v5",
                   "Humanoid-v5"]:
        kwargs = MAKE_KWARGS.get(env_id, {})
        eps = [
            run_episode(env_id, kwargs, name, seed, policy, state, max_steps)
            for name, seed, policy, state, max_steps in episodes(env_id)
        ]
        doc = {
            "env_id": env_id,
            "gymnasium_version": gym.__version__,
            "numpy_version": np.__version__,
            "mujoco_version": mujoco.__version__,
            "make_kwargs": kwargs,
            "episodes": eps,
        }
        path = FIXTURES / f"{env_id}.json"
        with path.open("w") as f:
            json.dump(doc, f, separators=(",", ":"))
            f.write("\n")
        steps = sum(len(e["actions"]) for e in eps)
        terms = sum(e["terminated"][-1] for e in eps)
        truncs = sum(e["truncated"][-1] for e in eps)
        lens = [len(e["actions"]) for e in eps]
        print(
            f"{path.relative_to(REPO)}: {len(eps)} episodes {lens}, {steps} steps, "
            f"{terms} terminated, {truncs} truncated, {path.stat().st_size} bytes"
        )


if __name__ == "__main__":
    main()
