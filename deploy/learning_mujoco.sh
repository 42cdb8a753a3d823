#!/usr/bin/env bash
# MBPO learning evidence on the MuJoCo tasks (issue 23, item 4): `mbpo bench learning` with 3 (--seeds)
# seeds each for Hopper-v5, HalfCheetah-v5, Walker2d-v5 and Ant-v5, evaluating 5 episodes every
# 1000 steps and keeping a checkpoint every 5000 (for `mbpo bench breakdown` and
# `mbpo bench diagnose`), then the curves with min..max bands over seeds.
#
#   bash deploy/learning_mujoco.sh [--steps 50000] [--tasks "hopper walker2d halfcheetah ant"]
#                                  [--seeds 3] [--out results] [--set KEY=VALUE]...
#                                  [--peer [LABEL=]FILE]...
#
# --seeds N runs seeds 0..N-1 of each task; raising it later adds seeds to a task whose first ones
# are done (they are reused), and the results file and plot then cover all N.
#
# Two lanes run side by side, one core each (sac.threads = model.threads = 1, as
# `mbpo bench learning` sets them for seeds run in parallel), taking seeds from one list in
# turn: first the seeds under way (with a checkpoint), then the others task by task. So both
# cores stay busy to the last seed whatever each task costs (a HalfCheetah seed, G = 40, costs
# far more than a Walker2d one). Each seed runs as `mbpo bench learning --only-seeds S`; the lane that
# completes a task's last seed writes <out>/learning-<env>.json (the benchmark over all seeds,
# which reuses their runs) and the plot.
#
# A variant of the paper's config goes to its own --out, e.g. the clipped imagined states on
# Walker2d and Hopper:
#   bash deploy/learning_mujoco.sh --tasks "walker2d hopper" --out results/clip-real-box \
#       --set mbpo.clip_imagined_states=real_box
# or is a config of its own whose env id differs, e.g. walker2d-v2-feet (gym:Walker2d-v5 with
# v2's feet): its runs and results files are named by that id beside the others.
#
# --peer puts a published curve file beside each task's results (`mbpo bench learning --peer`,
# `mbpo plot --peer`: mean ± std over its seeds in the results file, the table and the plot),
# e.g. the SimbaV2 authors' collection of Gym v4 baselines (dojeon-ai/SimbaV2 results/baseline):
#   --peer CrossQ=$DIR/crossq.csv --peer REDQ=$DIR/redq_utd20.csv
#
# Hours per seed: it is meant to run in the background across sessions, as a session of its own,
# which lets it lower its own share of the CPU (below):
#   mkdir -p results/runs; setsid nohup bash deploy/learning_mujoco.sh --tasks hopper \
#       > results/runs/lanes.log 2>&1 < /dev/null &
# Ctrl-C (or SIGTERM to the process group) checkpoints the seeds under way and stops; the same command
# continues each seed from its checkpoint and reuses the seeds already completed. When the lanes
# stop (done or Ctrl-C), deploy/park_runs.sh packs each run's curve and newest checkpoint into
# results/parked/ -- commit that, so a fresh checkout continues too: this script restores from it
# at the start whatever the run directories lack. Results: <out>/learning-<env>.json,
# <out>/learning-<env>.png (+ -losses.png), runs in <out>/runs/mbpo-<env>-s<seed>, each lane's
# log in <out>/runs/lane-<n>.log.
# The whole script is one group, read before it runs: bash reads a script as it goes, so an edit
# (or a git pull) while the lanes run hours would otherwise change the lines it has yet to run.
{
set -euo pipefail
cd "$(dirname "$0")/.."
steps=50000
seeds=3
tasks="hopper walker2d halfcheetah ant"
out=results
sets=()
peers=()
while [ $# -gt 0 ]; do
    case "$1" in
        --steps) steps=$2 ;;
        --tasks) tasks=$2 ;;
        --seeds) seeds=$2 ;;
        --out) out=$2 ;;
        --set) sets+=(--set "$2") ;;
        --peer) peers+=(--peer "$2") ;;
        *)
            echo "unknown argument $1: expected --steps N, --tasks \"a b\", --seeds N, --out DIR, --set KEY=VALUE or --peer [LABEL=]FILE" >&2
            exit 2
            ;;
    esac
    shift 2
done
if ! [[ "$seeds" =~ ^[1-9][0-9]*$ ]]; then
    echo "--seeds: expected a positive number of seeds, found '$seeds'" >&2
    exit 2
fi
for task in $tasks; do
    if [ ! -f "deploy/configs/$task.toml" ]; then
        echo "--tasks: no deploy/configs/$task.toml (tasks are config names, e.g. hopper)" >&2
        exit 2
    fi
done
budgets=$steps
if [ "$steps" -gt 20000 ]; then budgets="20000,$steps"; fi
source deploy/background.sh
yield_cpu_to_other_work
bash deploy/setup_mujoco.sh >&2
bash deploy/build.sh cli >&2
mbpo=./target/release/mbpo
mkdir -p "$out/runs"
bash deploy/park_runs.sh --restore

# Learn every task named, seeds one after another on one core, and plot each.
# The benchmark of one task (a config name), with the lanes' settings; more arguments appended.
bench() {
    local task=$1
    shift
    "$mbpo" bench learning --config "deploy/configs/$task.toml" --steps "$steps" --seeds "$seeds" \
        --threads 1 --budgets "$budgets" --set checkpoint.keep_every=5000 \
        --set eval.episodes=5 --set sac.threads=1 --set model.threads=1 "${sets[@]}" \
        --out "$out" "$@"
}

# The env as run directories and results files spell it: the config's `[gym] name` where it
# has one, else its id with `:` and `/` as `-` (gym:Walker2d-v5 -> gym-Walker2d-v5).
env_id() {
    local name
    name=$(sed -n 's/^name = "\(.*\)"/\1/p' "deploy/configs/$1.toml")
    if [ -n "$name" ]; then echo "$name"; return; fi
    sed -n 's/^env = "\(.*\)"/\1/p' "deploy/configs/$1.toml" | tr ':/' '--'
}
run_of() { echo "$out/runs/mbpo-$(env_id "$1")-s$2"; }
completed() { [ -f "$1/summary.json" ] && grep -q '"status": *"completed"' "$1/summary.json"; }
under_way() { compgen -G "$1/checkpoints/*/COMPLETE" >/dev/null; }

# Every seed of every task not completed yet, one "task seed" per line: those under way (with a
# checkpoint) first, so they go on where they were, then the others in task order.
jobs() {
    local pass task seed run
    for pass in under-way fresh; do
        for task in $tasks; do
            for seed in $(seq $((seeds - 1)) -1 0); do
                run=$(run_of "$task" "$seed")
                if completed "$run"; then continue; fi
                # `if`, not `[ ... ] && echo`: a false test as the function's last command
                # would be its exit status, and `set -e` would end the script at `jobs >`.
                if under_way "$run"; then
                    if [ "$pass" = under-way ]; then echo "$task $seed"; fi
                elif [ "$pass" = fresh ]; then
                    echo "$task $seed"
                fi
            done
        done
    done
}

# A lane takes the next seed no lane has taken (mkdir is the claim: atomic), runs it, and when
# that completed its task's last seed, writes the task's results file (the same benchmark over
# all seeds reuses the completed runs) and plots it. A seed that stops or fails ends the lane.
lane() {
    # A stop signal is for the benchmark, which checkpoints; the lane waits for it to exit.
    trap 'true' INT TERM
    local task seed id s
    local -a runs
    while read -r task seed; do
        mkdir "$claims/$task-s$seed" 2>/dev/null || continue
        bench "$task" --only-seeds "$seed"
        runs=()
        for s in $(seq 0 $((seeds - 1))); do
            completed "$(run_of "$task" "$s")" || continue 2
            runs+=("$(run_of "$task" "$s")")
        done
        bench "$task" "${peers[@]}"
        id=$(env_id "$task")
        "$mbpo" plot "${runs[@]}" --out "$out/learning-$id.png" "${peers[@]}" \
            --title "MBPO $id, $seeds seeds (mean, min..max)"
    done < "$claims/jobs"
}

# Claims of an earlier start are void: this script is the only one running the lanes.
claims="$out/runs/.claims"
rm -rf "$claims"
mkdir -p "$claims"
jobs > "$claims/jobs"
echo "seeds to run, in order: $(tr '\n' ',' < "$claims/jobs" | sed 's/,$//; s/,/, /g')" >&2
lane > "$out/runs/lane-1.log" 2>&1 &
first=$!
lane > "$out/runs/lane-2.log" 2>&1 &
second=$!
trap 'echo "stopping: the seeds under way checkpoint, then they are parked" >&2' INT TERM
status=0
wait_for "$first" || status=$?
wait_for "$second" || status=$?
bash deploy/park_runs.sh --with-checkpoints
[ "$status" = 0 ] || echo "a lane stopped (exit $status): see $out/runs/lane-*.log; rerun to continue" >&2
exit "$status"
}
