#!/usr/bin/env bash
# DeepMind Control Suite tasks for `env = "gym:dmc_env:make"` (tools/dmc_env.py): a venv of
# their own, <repo>/.venv-dmc, with dm_control, Gymnasium and NumPy from PyPI
# (tools/requirements-dmc.txt; dm_control needs MuJoCo >= 4, the project venv pins 3.17.0 for
# the native tasks). Run a DMC config with that interpreter:
#
#   bash deploy/setup_dmc.sh
#   MBPO_PYTHON=.venv-dmc/bin/python mbpo train --config deploy/configs/tdmpc-walker-walk.toml
#
# Idempotent; ends by stepping walker-walk once to show the env works.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv-dmc"
check='import sys; sys.path.insert(0, sys.argv[1]); import dmc_env; e = dmc_env.make("walker-walk"); o, _ = e.reset(seed=0); o, r, *_ = e.step(e.action_space.sample()); print(f"walker-walk: obs {o.shape[0]}, act {e.action_space.shape[0]}, one step reward {r:.3f}")'
if ! "$venv/bin/python" -c "import dm_control, gymnasium" 2>/dev/null; then
    if ! python3 -m venv --help >/dev/null 2>&1 || ! python3 -c "import ensurepip" 2>/dev/null; then
        apt-get install -y -qq python3-venv >/dev/null 2>&1 ||
            { apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null; }
    fi
    python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$repo/tools/requirements-dmc.txt"
fi
# Headless: dm_control picks a rendering backend at import; none is needed for state tasks.
MUJOCO_GL="${MUJOCO_GL:-disable}" "$venv/bin/python" -c "$check" "$repo/tools"
