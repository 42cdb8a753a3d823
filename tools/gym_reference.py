#!/usr/bin/env python3
"""Write Gymnasium reference trajectories as JSON fixtures for the Rust environments.

Regenerate (from the repository root):

    bash tools/setup_venv.sh && .venv/bin/python tools/gym_reference.py

This writes common/envs/tests/fixtures/<EnvId>.json, which
common/envs/tests/gymnasium_reference.rs replays with `reset_to` + `step`. The versions used are
pinned in tools/requirements.txt and recorded in every fixture.

Fixture format:

    {"env_id": str, "gymnasium_version": str, "numpy_version": str,
     "episodes": [{"name": str,
                   "state": [f64, ...],        # physical start state (Pendulum: theta,thetadot;
                                               #   MountainCar: position,velocity)
                   "actions": [[f32], ...],    # float32 values written as exact floats
                   "obs": [[f32, ...], ...],   # obs[0]: after setting the start state; then 1/step
                   "rewards": [f64, ...],
                   "terminated": [bool, ...],
                   "truncated": [bool, ...]}]}

How an episode is run: `gym.make(id)` (so the TimeLimit wrapper reports `truncated`),
`env.reset(seed=...)`, then `env.unwrapped.state` is overwritten with a float64 array, exactly the
dtype Gymnasium's own reset leaves there (this matters for MountainCarContinuous, whose first step
after reset runs in float64 and later steps in float32). Actions are float32 arrays of shape (1,).
An episode stops at `terminated` or `truncated`.

The results depend on the platform's libm (NumPy calls the system `pow`, `powf`, `sin` and `cos`);
the checked-in fixtures were made on x86-64 Debian 12 (glibc 2.36). Floats are written with
`repr`, which round-trips exactly; float32 values are converted with `float()` (exact).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np

REPO = Path(__file__).resolve().parent.parent
FIXTURES = REPO / "common" / "envs" / "tests" / "fixtures"


def obs_after_setting_state(env_id: str, unwrapped) -> np.ndarray:
    """The observation the environment reports for its current `state` (as its reset would)."""
    if env_id == "Pendulum-v1":
        return unwrapped._get_obs()
    # Continuous_MountainCarEnv.reset returns np.array(self.state, dtype=np.float32).
    return np.array(unwrapped.state, dtype=np.float32)


def run_episode(env_id: str, name: str, seed: int, state, policy) -> dict:
    """Run one episode from `state` (or from the seeded reset state when `state` is None).

    `policy(t, obs, rng)` returns the action as a float (it is converted to float32 here).
    """
    env = gym.make(env_id)
    env.reset(seed=seed)
    unwrapped = env.unwrapped
    if state is None:
        state = [float(x) for x in unwrapped.state]
    # Gymnasium's reset stores a float64 array in both environments; keep that dtype.
    unwrapped.state = np.array(state, dtype=np.float64)
    rng = np.random.default_rng(seed + 1000)
    obs = obs_after_setting_state(env_id, unwrapped)
    ep = {
        "name": name,
        "state": [float(x) for x in state],
        "actions": [],
        "obs": [[float(x) for x in obs]],
        "rewards": [],
        "terminated": [],
        "truncated": [],
    }
    t = 0
    while True:
        action = np.array([policy(t, obs, rng)], dtype=np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        assert obs.dtype == np.float32, obs.dtype
        ep["actions"].append([float(x) for x in action])
        ep["obs"].append([float(x) for x in obs])
        ep["rewards"].append(float(reward))
        ep["terminated"].append(bool(terminated))
        ep["truncated"].append(bool(truncated))
        t += 1
        if terminated or truncated:
            break
    env.close()
    return ep


def uniform(low: float, high: float):
    return lambda t, obs, rng: rng.uniform(low, high)


def constant(a: float):
    return lambda t, obs, rng: a


def pendulum_episodes() -> list[dict]:
    env_id = "Pendulum-v1"
    eps = []
    # Seeded reset states, actions wider than [-2, 2] (clipping) and in bounds.
    for seed in range(4):
        eps.append(run_episode(env_id, f"reset_seed{seed}_wide_actions", seed, None, uniform(-3, 3)))
    for seed in range(4, 6):
        eps.append(run_episode(env_id, f"reset_seed{seed}_inbound_actions", seed, None, uniform(-2, 2)))

    # Bang-bang with exact bounds and beyond, plus exact zeros.
    def bang(t, obs, rng):
        return [-3.0, -2.0, 0.0, 2.0, 3.0, -2.5, 2.5][int(rng.integers(7))]

    eps.append(run_episode(env_id, "bang_bang_exact_bounds", 6, [0.3, -0.2], bang))
    # Large |thetadot| at the speed limit, pushed further: exercises the clip at +-8.
    eps.append(run_episode(env_id, "thetadot_near_8_push", 7, [3.0, 7.9], constant(2.0)))
    eps.append(run_episode(env_id, "thetadot_8_wide", 8, [-2.5, 8.0], uniform(-3, 3)))
    # theta outside [-pi, pi]: the state is not wrapped, only the cost normalises the angle.
    eps.append(run_episode(env_id, "theta_10.5_thetadot_-7.95", 9, [10.5, -7.95], uniform(-3, 3)))
    eps.append(run_episode(env_id, "theta_-20_thetadot_7.99", 10, [-20.0, 7.99], uniform(-2, 2)))
    eps.append(run_episode(env_id, "theta_100_thetadot_-8", 11, [100.0, -8.0], uniform(-3, 3)))
    # Unstable equilibrium exactly at pi (angle_normalize(pi) = -pi).
    eps.append(run_episode(env_id, "upright_pi_zero_action", 12, [math.pi, 0.0], constant(0.0)))
    eps.append(run_episode(env_id, "hanging_zero_state", 13, [0.0, 0.0], uniform(-0.1, 0.1)))
    return eps


def mountain_car_episodes() -> list[dict]:
    env_id = "MountainCarContinuous-v0"
    eps = []
    # Full-length (999-step, truncated) episodes from seeded reset states.
    for seed in range(3):
        eps.append(run_episode(env_id, f"reset_seed{seed}_wide_actions", seed, None, uniform(-1.6, 1.6)))
    eps.append(run_episode(env_id, "reset_seed3_inbound_actions", 3, None, uniform(-1, 1)))

    # Energy pumping: push along the velocity. Reaches the goal -> terminated (reward +100).
    def pump(scale):
        return lambda t, obs, rng: scale if obs[1] >= 0 else -scale

    eps.append(run_episode(env_id, "pump_inbound_reaches_goal", 4, None, pump(1.0)))
    # Same with |a| = 1.5: clipped force, unclipped action in the reward penalty.
    eps.append(run_episode(env_id, "pump_wide_reaches_goal", 5, None, pump(1.5)))

    def noisy_pump(t, obs, rng):
        return (1.0 if obs[1] >= 0 else -1.0) * rng.uniform(0.5, 1.6)

    eps.append(run_episode(env_id, "noisy_pump_reaches_goal", 6, [-0.45, 0.0], noisy_pump))

    # Left wall: driven into p = -1.2, where v is reset to 0; then random actions.
    def left_then_random(t, obs, rng):
        return -1.0 if t < 80 else rng.uniform(-1.6, 1.6)

    eps.append(run_episode(env_id, "left_wall_then_random", 7, [-0.9, -0.04], left_then_random))
    # Hits the wall on the very first step (float64 step).
    eps.append(run_episode(env_id, "left_wall_first_step", 8, [-1.19, -0.05], pump(1.2)))
    # Speed limit: the first step (float64) and later steps (float32) clip v at +0.07.
    eps.append(run_episode(env_id, "speed_clip_first_step", 9, [-0.52, 0.0695], constant(1.0)))
    eps.append(run_episode(env_id, "speed_clip_later_step", 13, [-0.6, 0.066], constant(1.0)))
    eps.append(run_episode(env_id, "speed_clip_negative", 10, [0.3, -0.069], constant(-1.5)))
    # Right wall: clipped to 0.6 and terminated on the first step.
    eps.append(run_episode(env_id, "right_wall_first_step", 11, [0.55, 0.07], constant(0.0)))
    # Goal reached with an exact-bound action.
    eps.append(run_episode(env_id, "goal_exact_bound_action", 12, [0.4, 0.04], constant(1.0)))
    # Lands exactly on float32(0.45) = 0.44999998807907104 at step 2 (a float32 step): NumPy
    # compares `position >= 0.45` in float32, so this terminates; a float64 comparison would not.
    # The start velocity was found by bisection on the step-2 position.
    ep = run_episode(env_id, "goal_edge_float32_comparison", 14, [0.35, 0.051695275236852474], constant(0.0))
    assert ep["obs"][2][0] == float(np.float32(0.45)) and ep["terminated"] == [False, True], ep
    eps.append(ep)
    return eps


def main() -> None:
    warnings.filterwarnings("ignore")  # the env checker warns about out-of-box start states
    FIXTURES.mkdir(parents=True, exist_ok=True)
    for env_id, make_eps in [
        ("Pendulum-v1", pendulum_episodes),
        ("MountainCarContinuous-v0", mountain_car_episodes),
    ]:
        episodes = make_eps()
        doc = {
            "env_id": env_id,
            "gymnasium_version": gym.__version__,
            "numpy_version": np.__version__,
            "episodes": episodes,
        }
        path = FIXTURES / f"{env_id}.json"
        with path.open("w") as f:
            json.dump(doc, f, separators=(",", ":"))
            f.write("\n")
        steps = sum(len(e["actions"]) for e in episodes)
        terms = sum(e["terminated"][-1] for e in episodes)
        truncs = sum(e["truncated"][-1] for e in episodes)
        print(
            f"{path.relative_to(REPO)}: {len(episodes)} episodes, {steps} steps, "
            f"{terms} terminated, {truncs} truncated, {path.stat().st_size} bytes"
        )


if __name__ == "__main__":
    main()
