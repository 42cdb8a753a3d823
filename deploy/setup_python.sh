#!/usr/bin/env bash
# The Python side of `env = "gym:..."`: the project venv <repo>/.venv with Gymnasium and NumPy
# (tools/setup_venv.sh; installs python3-venv with apt if needed), which `mbpo` uses by default
# for Python envs (override: `python = ...` in the config's [gym] table, or MBPO_PYTHON).
# Extra arguments are pip requirements installed into that venv: your env's own packages.
#
#   bash deploy/setup_python.sh                      # Gymnasium + NumPy
#   bash deploy/setup_python.sh gymnasium-robotics   # ... plus a package your env needs
#   bash deploy/setup_python.sh -e ./my_envs         # ... or your own package, editable
#
# Idempotent and fast when everything is in place. (deploy/setup_mujoco.sh runs it too.)
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if ! "$repo/.venv/bin/python" -c "import gymnasium, numpy" 2>/dev/null; then
    bash "$repo/tools/setup_venv.sh"
fi
if [ $# -gt 0 ]; then
    "$repo/.venv/bin/python" -m pip install --quiet --disable-pip-version-check "$@"
fi
echo "setup_python: $("$repo/.venv/bin/python" -c 'import gymnasium, numpy, sys; print(f"Python {sys.version.split()[0]}, gymnasium {gymnasium.__version__}, numpy {numpy.__version__}")') in $repo/.venv"
