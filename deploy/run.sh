#!/usr/bin/env bash
# The main job: build in release mode and train on the embedded default task (Pendulum-v1).
# Extra arguments are passed to `mbpo train`, e.g. `bash deploy/run.sh --seed 3 --steps 5000`.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -p mbpo
exec ./target/release/mbpo train --config deploy/configs/sac-pendulum.toml "$@"
