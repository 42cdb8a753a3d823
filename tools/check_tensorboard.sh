#!/usr/bin/env bash
# Check the TensorBoard event files mbpo writes with the real TensorBoard (Python package).
#
# 1. .venv with TensorBoard (tools/setup_venv.sh + tools/requirements-tensorboard.txt, PyPI only);
# 2. a tiny SAC run and a tiny MBPO run (release build), plus a run directory written the way a
#    resumed run writes it (common/train/examples/tb_resume_fixture.rs);
# 3. tools/check_tensorboard.py reads every event file with TensorBoard's readers and compares
#    each scalar with metrics.csv, and checks the resumed run shows the right points.
#
# Not part of CI (it installs TensorBoard, ~30 MB, and takes about a minute).
# Usage: bash tools/check_tensorboard.sh [OUT_DIR]   (default: a fresh temporary directory)
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-$(mktemp -d /tmp/mbpo-tb-check.XXXXXX)}"
cd "$repo"

bash tools/setup_venv.sh
.venv/bin/python -m pip install --quiet --disable-pip-version-check -r tools/requirements-tensorboard.txt

cargo build --release --locked -p mbpo -p mbpo-train --bin mbpo --example tb_resume_fixture
mbpo=target/release/mbpo

"$mbpo" train --config deploy/configs/sac-pendulum.toml --steps 3000 --out "$out/sac-Pendulum-v1-s0" >/dev/null
"$mbpo" train --config deploy/configs/pendulum-tiny.toml --steps 600 --out "$out/mbpo-Pendulum-v1-s0" >/dev/null
target/release/examples/tb_resume_fixture "$out/resumed" >/dev/null

.venv/bin/python tools/check_tensorboard.py "$out/sac-Pendulum-v1-s0" "$out/mbpo-Pendulum-v1-s0" --resumed "$out/resumed"
