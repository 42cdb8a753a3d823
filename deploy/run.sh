#!/usr/bin/env bash
# The main job: build in release mode and run MBPO as the multi-process pipeline (actor,
# evaluator, model trainer, rollout generator, SAC learner over iceoryx2 shared memory, under
# the `mbpo run` supervisor) on the embedded default task, Pendulum-v1.
# Extra arguments go to `mbpo run`, e.g. `bash deploy/run.sh --seed 3 --steps 2000 --out runs/try`
# or `bash deploy/run.sh --mode lockstep` (bit-identical to `mbpo train --mode sequential`).
set -euo pipefail
exec bash "$(dirname "$0")/supervise.sh" "$@"
