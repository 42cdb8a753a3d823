#!/usr/bin/env bash
# Launch the MBPO pipeline supervisor (`mbpo run`): builds the supervisor and the four service
# binaries in release mode (deploy/build.sh; with --listen also the gateway) and runs the pipeline.
#
#   bash deploy/supervise.sh                                   # the default job (configs/demo.toml)
#   bash deploy/supervise.sh --mode lockstep --steps 2000      # bit-identical to `mbpo train --mode sequential`
#   bash deploy/supervise.sh --actors 2 --pin-cpus             # two actors, one CPU each
#   bash deploy/supervise.sh --config deploy/configs/pendulum-tiny.toml --out runs/tiny
#
# Every flag is passed to `mbpo run` (see `mbpo run --help`); --config defaults to
# deploy/configs/demo.toml (MBPO on Pendulum-v1, ending once solved). Logs of each process: <run-dir>/logs/<process>.log.
# Ctrl-C (SIGINT) or SIGTERM stops every process within seconds and removes the run's shared memory.
# A config of a MuJoCo task (e.g. deploy/configs/halfcheetah.toml) first runs
# deploy/setup_mujoco.sh, so the build has the `mujoco` feature.
set -euo pipefail
cd "$(dirname "$0")/.."
args=("$@")
if [[ " ${args[*]-} " != *" --config "* ]]; then
  args=(--config deploy/configs/demo.toml "${args[@]}")
fi
# A head that admits actors of other hosts (--listen) also starts the gateway.
role=pipeline
for ((i = 0; i < ${#args[@]}; i++)); do
  if [[ ${args[i]} == --listen || ${args[i]} == --listen=* ]]; then
    role=head
  fi
  if [[ ${args[i]} == --config ]] && ((i + 1 < ${#args[@]})) \
    && grep -qE '^[[:space:]]*env[[:space:]]*=[[:space:]]*"(InvertedPendulum|HalfCheetah|Hopper|Walker2d|Ant)-v5"' "${args[i + 1]}"; then
    bash deploy/setup_mujoco.sh
  fi
done
bash deploy/build.sh "$role"
exec ./target/release/mbpo run "${args[@]}"
