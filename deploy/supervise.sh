#!/usr/bin/env bash
# Launch the MBPO pipeline supervisor (`mbpo run`): builds the supervisor and the four service
# binaries in release mode (they must sit next to each other) and runs the pipeline.
#
#   bash deploy/supervise.sh                                   # Pendulum-v1, MBPO config, pipelined
#   bash deploy/supervise.sh --mode lockstep --steps 2000      # bit-identical to `mbpo train --mode sequential`
#   bash deploy/supervise.sh --actors 2 --pin-cpus             # two actors, one CPU each
#   bash deploy/supervise.sh --config deploy/configs/pendulum-tiny.toml --out runs/tiny
#
# Every flag is passed to `mbpo run` (see `mbpo run --help`); --config defaults to
# deploy/configs/pendulum.toml. Logs of each process: <run-dir>/logs/<process>.log.
# Ctrl-C (SIGINT) or SIGTERM stops every process within seconds and removes the run's shared memory.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -p mbpo -p mbpo-actor -p mbpo-model-trainer -p mbpo-rollout-generator -p mbpo-sac-learner
args=("$@")
if [[ " ${args[*]-} " != *" --config "* ]]; then
  args=(--config deploy/configs/pendulum.toml "${args[@]}")
fi
exec ./target/release/mbpo run "${args[@]}"
