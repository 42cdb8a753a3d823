#!/usr/bin/env python3
"""How often Hopper's and Walker2d's observed joint velocities sit at the env's clip (issue 23).

Gymnasium's Hopper and Walker2d (v2 to v5) observe qvel clipped to [-10, 10]. `mbpo bench
diagnose` found half of Walker2d's imagined next states outside the box of all real states (in
joint velocities, at k = 1) against 0.2 % for Hopper, and a model holdout MSE about 60x Hopper's.
This measures the real side of that: uniform random actions (MBPO's first 5000 steps), the share
of transitions whose next observation has a velocity at the clip, per velocity dimension, and the
spread of the one-step change the model has to predict. Walker2d-v4 has the v2 model file (the
paper's, but for the right foot's friction) on the same MuJoCo.

    .venv/bin/python tools/velocity_saturation.py [--steps 5000] [--out results/velocity-saturation.json]

(`bash deploy/setup_mujoco.sh` makes .venv with the pinned mujoco and gymnasium.) With
`--engine-only XML` it steps a Walker2d or Hopper model file with MuJoCo alone (Gymnasium's
reset noise, frame skip 4, health rule and time limit written out here), so the same count can
be taken under another MuJoCo release in a venv of its own, e.g.

    python3 -m venv /tmp/mj && /tmp/mj/bin/pip install --only-binary=:all: mujoco==2.3.1.post1 "numpy<2"
    /tmp/mj/bin/python tools/velocity_saturation.py --engine-only \
        .venv/lib/python3.11/site-packages/gymnasium/envs/mujoco/assets/walker2d.xml
"""
import argparse
import json
import sys
import warnings

import numpy as np

TASKS = ["Hopper-v5", "Walker2d-v5", "Walker2d-v4"]
CLIP = 10.0


def measure(env_id, steps, seed):
    import gymnasium as gym

    # After the import: gymnasium sets its own filter for its "out of date" warning (v4).
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    env = gym.make(env_id)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    before, after = [], []
    for _ in range(steps):
        action = rng.uniform(env.action_space.low, env.action_space.high)
        next_obs, _, terminated, truncated, _ = env.step(action)
        before.append(obs)
        after.append(next_obs)
        obs = next_obs
        if terminated or truncated:
            obs, _ = env.reset()
    before, after = np.array(before), np.array(after)
    # The observation is qpos[1:] then clip(qvel): nq - 1 + nv values with nv = nq - 1 here
    # (one free slide x is left out), so the velocities are the last nv = (dim + 1) // 2.
    nv = (after.shape[1] + 1) // 2
    velocities = after[:, -nv:]
    at_clip = np.abs(velocities) >= CLIP * (1 - 1e-6)
    delta = after - before
    return {
        "env": env_id,
        "transitions": steps,
        "velocity_dims": list(range(after.shape[1] - nv, after.shape[1])),
        "rows_with_a_velocity_at_clip": float(at_clip.any(axis=1).mean()),
        "at_clip_by_velocity_dim": [round(float(x), 4) for x in at_clip.mean(axis=0)],
        "delta_std_by_dim": [round(float(x), 4) for x in delta.std(axis=0)],
    }


def measure_engine_only(xml, steps, seed):
    """The share of steps with a joint or root velocity at the clip, MuJoCo alone.

    Gymnasium's Hopper and Walker2d loop without Gymnasium: reset noise U(-5e-3, 5e-3) on qpos and
    qvel, 4 physics steps per env step, healthy while z and the torso angle are in the task's
    ranges (Walker2d (0.8, 2) and (-1, 1); Hopper z > 0.7, |angle| < 0.2), 1000-step episodes.
    """
    import mujoco

    model = mujoco.MjModel.from_xml_path(xml)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    hopper = "hopper" in xml.rsplit("/", 1)[-1]
    init_qpos, init_qvel = data.qpos.copy(), data.qvel.copy()

    def reset():
        mujoco.mj_resetData(model, data)
        data.qpos[:] = init_qpos + rng.uniform(-5e-3, 5e-3, model.nq)
        data.qvel[:] = init_qvel + rng.uniform(-5e-3, 5e-3, model.nv)
        mujoco.mj_forward(model, data)

    def healthy():
        z, angle = data.qpos[1], data.qpos[2]
        return z > 0.7 and abs(angle) < 0.2 if hopper else 0.8 < z < 2.0 and -1 < angle < 1

    reset()
    at_clip, t = [], 0
    for _ in range(steps):
        data.ctrl[:] = rng.uniform(-1, 1, model.nu)
        for _ in range(4):
            mujoco.mj_step(model, data)
        t += 1
        at_clip.append(np.abs(data.qvel) >= CLIP)
        if not healthy() or t >= 1000:
            reset()
            t = 0
    at_clip = np.array(at_clip)
    return {
        "model_file": xml,
        "mujoco": mujoco.__version__,
        "transitions": steps,
        "rows_with_a_velocity_at_clip": float(at_clip.any(axis=1).mean()),
        "at_clip_by_qvel": [round(float(x), 4) for x in at_clip.mean(axis=0)],
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="also write the JSON lines' list here")
    parser.add_argument("--engine-only", metavar="XML", help="step this model file with MuJoCo alone")
    args = parser.parse_args()
    if args.steps < 1:
        sys.exit(f"--steps: expected a positive number of transitions, found {args.steps}")
    if args.engine_only:
        try:
            print(json.dumps(measure_engine_only(args.engine_only, args.steps, args.seed)))
        except ValueError as error:  # MuJoCo's own message names the file and what is wrong
            sys.exit(f"--engine-only {args.engine_only}: {error}")
        return
    results = [measure(task, args.steps, args.seed) for task in TASKS]
    for result in results:
        print(json.dumps(result))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1)
            f.write("\n")


if __name__ == "__main__":
    main()
