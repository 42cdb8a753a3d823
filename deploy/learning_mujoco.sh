#!/usr/bin/env bash
# MBPO learning evidence on the MuJoCo tasks (issue 23, item 4): `mbpo bench learning` with 3
# seeds each for Hopper-v5, HalfCheetah-v5, Walker2d-v5 and Ant-v5, evaluating 5 episodes every
# 1000 steps and keeping a checkpoint every 5000 (for `mbpo bench breakdown` and
# `mbpo bench diagnose`), then the curves with min..max bands over seeds.
#
#   bash deploy/learning_mujoco.sh [--steps 50000] [ENV ...]     # ENV: hopper halfcheetah walker2d ant
#
# Hours per seed: it is meant to run niced in the background across sessions. Ctrl-C (or
# SIGTERM) checkpoints the seeds under way and stops; the same command continues each seed from
# its checkpoint and reuses the seeds already completed. Results: results/learning-<env>.json,
# results/learning-<env>.png (+ -losses.png), runs in results/runs/mbpo-<env>-s<seed>.
set -euo pipefail
cd "$(dirname "$0")/.."
steps=50000
if [ "${1:-}" = "--steps" ]; then
    steps=$2
    shift 2
fi
envs=("$@")
[ ${#envs[@]} -gt 0 ] || envs=(hopper halfcheetah walker2d ant)
bash deploy/setup_mujoco.sh >&2
cargo build --release --locked -p mbpo --features mujoco >&2
mbpo=./target/release/mbpo
for env in "${envs[@]}"; do
    config=deploy/configs/$env.toml
    [ -f "$config" ] || { echo "no config $config (one of: hopper halfcheetah walker2d ant)" >&2; exit 2; }
    # Two seeds side by side, one core each (the bench sets the thread counts to 1 per seed).
    "$mbpo" bench learning --config "$config" --steps "$steps" --seeds 3 --threads 2 \
        --budgets "20000,$steps" --set checkpoint.keep_every=5000 --set eval.episodes=5 \
        --out results
    id=$(grep -m1 '^env = ' "$config" | sed 's/env = "\(.*\)"/\1/')
    "$mbpo" plot results/runs/mbpo-"$id"-s0 results/runs/mbpo-"$id"-s1 results/runs/mbpo-"$id"-s2 \
        --out "results/learning-$id.png" --title "MBPO $id, 3 seeds (min..max)"
done
