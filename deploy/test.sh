#!/usr/bin/env bash
# Runs the whole test suite: unit tests, gradient checks, Gymnasium replays, learning tests.
# The default build needs only the Rust toolchain (Gymnasium fixtures are committed; see
# tools/gym_reference.py). The MuJoCo tasks (cargo feature `mujoco`) need libmujoco 3.17.0:
# deploy/setup_mujoco.sh installs it from PyPI into the project venv (idempotent, about a
# second when already done), then their replays against Gymnasium and the config checks run.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --workspace --locked "$@"
bash deploy/setup_mujoco.sh
cargo test --locked -p mbpo-envs -p mbpo-train --features mujoco "$@"
