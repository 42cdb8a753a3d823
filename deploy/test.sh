#!/usr/bin/env bash
# Runs the whole test suite: unit tests, gradient checks, Gymnasium replays, learning tests.
# The default build needs only the Rust toolchain (Gymnasium fixtures are committed; see
# tools/gym_reference.py); the Python env bridge's tests (`env = "gym:..."`) need the project
# venv with Gymnasium, which deploy/setup_python.sh makes first (idempotent). The MuJoCo tasks (cargo feature `mujoco`) need libmujoco 3.17.0:
# deploy/setup_mujoco.sh installs it from PyPI into the project venv (idempotent, about a
# second when already done), then their replays against Gymnasium and the config checks run
# (mbpo-envs, mbpo-config's and mbpo-train's unit tests and a tiny MBPO run per MuJoCo config family, to keep CI
# short).
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/setup_python.sh
# The multi-host tests make network namespaces (as root) with iproute2's `ip`.
if ! command -v ip >/dev/null && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get install -y -qq iproute2 >/dev/null 2>&1 ||
        { apt-get update -qq && apt-get install -y -qq iproute2 >/dev/null; }
fi
# tests/tests/cross_cpu.rs runs MBPO on CPUs that QEMU's user mode emulates (Debian's qemu-user).
if ! command -v qemu-x86_64 >/dev/null && [ "$(uname -m)" = x86_64 ] && [ "$(id -u)" = 0 ] &&
    command -v apt-get >/dev/null; then
    apt-get install -y -qq qemu-user >/dev/null 2>&1 ||
        { apt-get update -qq && apt-get install -y -qq qemu-user >/dev/null; }
fi
cargo test --workspace --locked "$@"
status=0
bash deploy/setup_mujoco.sh || status=$?
if [ "$status" = 3 ]; then
    echo "deploy/test.sh: the MuJoCo tests are skipped: this CPU cannot run MuJoCo's library (above)" >&2
    exit 0
elif [ "$status" != 0 ]; then
    exit "$status"
fi
cargo test --locked -p mbpo-envs --features mujoco "$@"
cargo test --locked -p mbpo-config --features mujoco --lib "$@"
cargo test --locked -p mbpo-train --features mujoco --lib --test mujoco_tasks --test resume "$@"
cargo test --locked -p mbpo-bench --features mujoco --test diagnose "$@"
