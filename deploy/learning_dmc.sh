#!/usr/bin/env bash
# TD-MPC2 on DeepMind Control (issue 61): `mbpo bench learning` of each task's config
# (deploy/configs/tdmpc-<task>.toml, the paper's 1M preset on CPU) over 3 seeds to 100k env
# steps, one seed at a time on one core, then the plot and table of each task beside TD-MPC2's,
# DreamerV3's and SAC's published curves.
#
#   bash deploy/learning_dmc.sh [--tasks "walker-walk cartpole-swingup"] [--seeds 3]
#                               [--steps 100000] [--out results] [--published DIR]
#
# --published DIR is the tdmpc2 repository's results folder (nicklashansen/tdmpc2 results/, with
# tdmpc2/, dreamerv3/ and sac/ in it): its curves of each task go into the results file
# (`published` of the `tdmpc` entry of <out>/learning-dmc-<task>.json) and the plot
# (<out>/learning-tdmpc-dmc-<task>.png, the table beside it as .md). Without it the results
# keep the curves given before, and the plot has ours only.
#
# Resumable like deploy/learning_mujoco.sh: Ctrl-C (or SIGTERM to the process group)
# checkpoints the seed under way; the same command continues it from its checkpoint and reuses
# the seeds already completed. It is hours per seed (about 7 h of one core at walker-walk's
# sizes, 2026-12-05), meant to run in the background beside other work, as a session of its
# own, which lowers its own share of the CPU (deploy/background.sh says how):
#   mkdir -p results/runs; setsid nohup bash deploy/learning_dmc.sh --published $R \
#       >> results/runs/dmc.log 2>&1 < /dev/null &
# Runs in <out>/runs/tdmpc-dmc-<task>-s<seed>, each task's log in <out>/runs/dmc-<task>.log;
# parked (deploy/park_runs.sh --with-checkpoints: curves and the newest checkpoint, for a fresh
# checkout) when it stops, restored when it starts.
# The whole script is one group, read before it runs (an edit while it runs changes nothing).
{
set -euo pipefail
cd "$(dirname "$0")/.."
tasks="walker-walk cartpole-swingup"
seeds=3
steps=100000
out=results
published=""
while [ $# -gt 0 ]; do
    case "$1" in
        --tasks) tasks=$2 ;;
        --seeds) seeds=$2 ;;
        --steps) steps=$2 ;;
        --out) out=$2 ;;
        --published) published=$2 ;;
        *)
            echo "unknown argument $1: expected --tasks \"a b\", --seeds N, --steps N, --out DIR or --published DIR" >&2
            exit 2
            ;;
    esac
    shift 2
done
for task in $tasks; do
    if [ ! -f "deploy/configs/tdmpc-$task.toml" ]; then
        echo "--tasks: no deploy/configs/tdmpc-$task.toml (tasks are DMC names, e.g. walker-walk)" >&2
        exit 2
    fi
    for method in tdmpc2 dreamerv3 sac; do
        if [ -n "$published" ] && [ ! -f "$published/$method/$task.csv" ]; then
            echo "--published: no $published/$method/$task.csv (the tdmpc2 repository's results folder)" >&2
            exit 2
        fi
    done
done
source deploy/background.sh
yield_cpu_to_other_work
bash deploy/setup_dmc.sh >&2
bash deploy/build.sh cli >&2
mbpo=./target/release/mbpo
mkdir -p "$out/runs"
bash deploy/park_runs.sh --restore
# A stop signal is for the benchmark, which checkpoints; this script waits for it to exit.
trap 'echo "stopping: the seed under way checkpoints" >&2' INT TERM
for task in $tasks; do
    peers=()
    if [ -n "$published" ]; then
        peers=(--peer "TD-MPC2=$published/tdmpc2/$task.csv"
               --peer "DreamerV3=$published/dreamerv3/$task.csv"
               --peer "SAC=$published/sac/$task.csv")
    fi
    log="$out/runs/dmc-$task.log"
    echo "$task: $seeds seeds to $steps env steps (log: $log)" >&2
    MBPO_PYTHON=.venv-dmc/bin/python "$mbpo" bench learning \
        --config "deploy/configs/tdmpc-$task.toml" --seeds "$seeds" --steps "$steps" \
        --threads 1 --budgets "50000,$steps" --out "$out" "${peers[@]}" >> "$log" 2>&1 &
    if ! wait_for "$!"; then
        bash deploy/park_runs.sh --with-checkpoints
        echo "$task stopped: see $log; rerun the same command to continue" >&2
        exit 1
    fi
    runs=()
    for s in $(seq 0 $((seeds - 1))); do runs+=("$out/runs/tdmpc-dmc-$task-s$s"); done
    "$mbpo" plot "${runs[@]}" --out "$out/learning-tdmpc-dmc-$task.png" --table-every 10000 \
        "${peers[@]}" --title "TD-MPC2 (ours, 1M preset) on DMC $task, $seeds seeds" >&2
done
bash deploy/park_runs.sh --with-checkpoints
}
