#!/usr/bin/env bash
# Create (or update) the Python venv used by the tools in this folder, at <repo>/.venv (gitignored).
#
# Idempotent: re-running keeps an existing venv and only installs what the pins say is missing.
# Works on a fresh Debian machine with Python 3.11; if `python3 -m venv` fails for lack of
# ensurepip (Debian ships it separately), python3-venv is installed with apt-get.
# Packages come only from PyPI, pinned in tools/requirements.txt.
#
# Usage: bash tools/setup_venv.sh && .venv/bin/python tools/gym_reference.py
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
python="${PYTHON:-python3}"

if ! command -v "$python" >/dev/null 2>&1; then
    echo "setup_venv: $python not found; installing python3 with apt-get" >&2
    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3
fi

if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
    rm -rf "$venv"
    if ! "$python" -m venv "$venv" 2>/dev/null; then
        rm -rf "$venv"
        echo "setup_venv: '$python -m venv' failed (no ensurepip?); installing python3-venv" >&2
        ver="$("$python" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
        apt-get update -q
        # Debian names the package after the minor version (python3.11-venv); python3-venv
        # depends on it for the default interpreter.
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q "python${ver}-venv" \
            || DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv
        "$python" -m venv "$venv"
    fi
fi

"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$repo/tools/requirements.txt"
"$venv/bin/python" - <<'PY'
import gymnasium, numpy
print(f"setup_venv: gymnasium {gymnasium.__version__}, numpy {numpy.__version__}")
PY
