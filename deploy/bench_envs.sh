#!/usr/bin/env bash
# Environment steps per second, Rust (`mbpo bench env`, with the MuJoCo tasks) against Gymnasium
# (tools/gym_env_speed.py), in one run on the same machine: one JSON line per environment and
# implementation. Sets up MuJoCo first (deploy/setup_mujoco.sh; fast when already done).
#
#   bash deploy/bench_envs.sh [--seconds 2]
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/setup_mujoco.sh >&2
bash deploy/build.sh cli >&2
echo "load: $(uptime)" >&2
./target/release/mbpo bench env "$@"
.venv/bin/python tools/gym_env_speed.py "$@"
