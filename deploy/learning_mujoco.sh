#!/usr/bin/env bash
# MBPO learning evidence on the MuJoCo tasks (issue 23, item 4): `mbpo bench learning` with 3
# seeds each for Hopper-v5, HalfCheetah-v5, Walker2d-v5 and Ant-v5, evaluating 5 episodes every
# 1000 steps and keeping a checkpoint every 5000 (for `mbpo bench breakdown` and
# `mbpo bench diagnose`), then the curves with min..max bands over seeds.
#
#   bash deploy/learning_mujoco.sh [--steps 50000] [--tasks "hopper walker2d halfcheetah ant"]
#                                  [--out results] [--set KEY=VALUE]...
#
# Two lanes run side by side, one core each (sac.threads = model.threads = 1, as
# `mbpo bench learning` sets them for seeds run in parallel), each seed after the other; the
# tasks alternate between them: by default Hopper then HalfCheetah, and Walker2d then Ant. So both
# cores stay busy to the last seed (one benchmark of 3 seeds on 2 cores would leave one idle for
# its third seed).
#
# A variant of the paper's config goes to its own --out, e.g. the clipped imagined states on
# Walker2d and Hopper:
#   bash deploy/learning_mujoco.sh --tasks "walker2d hopper" --out results/clip-real-box \
#       --set mbpo.clip_imagined_states=real_box
#
# Hours per seed: it is meant to run niced in the background across sessions. Ctrl-C (or
# SIGTERM to the process group) checkpoints the seeds under way and stops; the same command
# continues each seed from its checkpoint and reuses the seeds already completed. When the lanes
# stop (done or Ctrl-C), deploy/park_runs.sh packs each run's curve and newest checkpoint into
# results/parked/ -- commit that, so a fresh checkout continues too: this script restores from it
# at the start whatever the run directories lack. Results: <out>/learning-<env>.json,
# <out>/learning-<env>.png (+ -losses.png), runs in <out>/runs/mbpo-<env>-s<seed>, each lane's
# log in <out>/runs/lane-<n>.log.
set -euo pipefail
cd "$(dirname "$0")/.."
steps=50000
tasks="hopper walker2d halfcheetah ant"
out=results
sets=()
while [ $# -gt 0 ]; do
    case "$1" in
        --steps) steps=$2 ;;
        --tasks) tasks=$2 ;;
        --out) out=$2 ;;
        --set) sets+=(--set "$2") ;;
        *)
            echo "unknown argument $1: expected --steps N, --tasks \"a b\", --out DIR or --set KEY=VALUE" >&2
            exit 2
            ;;
    esac
    shift 2
done
for task in $tasks; do
    if [ ! -f "deploy/configs/$task.toml" ]; then
        echo "--tasks: no deploy/configs/$task.toml (tasks are config names, e.g. hopper)" >&2
        exit 2
    fi
done
bash deploy/setup_mujoco.sh >&2
cargo build --release --locked -p mbpo --features mujoco >&2
mbpo=./target/release/mbpo
mkdir -p "$out/runs"
bash deploy/park_runs.sh --restore

# Learn every task named, seeds one after another on one core, and plot each.
lane() {
    # A stop signal is for the benchmark, which checkpoints; the lane waits for it to exit.
    trap 'true' INT TERM
    for task in "$@"; do
        local config=deploy/configs/$task.toml
        "$mbpo" bench learning --config "$config" --steps "$steps" --seeds 3 --threads 1 \
            --budgets "20000,$steps" --set checkpoint.keep_every=5000 --set eval.episodes=5 \
            --set sac.threads=1 --set model.threads=1 "${sets[@]}" --out "$out"
        local id
        id=$(sed -n 's/^env = "\(.*\)"/\1/p' "$config")
        "$mbpo" plot "$out"/runs/mbpo-"$id"-s0 "$out"/runs/mbpo-"$id"-s1 \
            "$out"/runs/mbpo-"$id"-s2 --out "$out/learning-$id.png" \
            --title "MBPO $id, 3 seeds (mean, min..max)"
    done
}

# Wait for lane `$1` to exit and return its status. A signal to this script interrupts `wait`
# (the trap below), not the lane: its benchmark checkpoints first, so wait again until it is gone.
wait_for() {
    local status=0
    while true; do
        wait "$1" && return 0 || status=$?
        kill -0 "$1" 2>/dev/null || return "$status"
    done
}

# Tasks 1, 3, ... on lane 1 and 2, 4, ... on lane 2.
lane_tasks() {
    local i=0 task
    for task in $tasks; do
        if [ $((i % 2)) = "$1" ]; then echo "$task"; fi
        i=$((i + 1))
    done
}
# shellcheck disable=SC2046 # one word per task
lane $(lane_tasks 0) > "$out/runs/lane-1.log" 2>&1 &
first=$!
# shellcheck disable=SC2046
lane $(lane_tasks 1) > "$out/runs/lane-2.log" 2>&1 &
second=$!
trap 'echo "stopping: the seeds under way checkpoint, then they are parked" >&2' INT TERM
status=0
wait_for "$first" || status=$?
wait_for "$second" || status=$?
bash deploy/park_runs.sh
[ "$status" = 0 ] || echo "a lane stopped (exit $status): see $out/runs/lane-*.log; rerun to continue" >&2
exit "$status"
