#!/usr/bin/env bash
# MBPO on Pendulum-v1 (deploy/configs/pendulum.toml: G = 20, M = 400, 7 x 4x200) or, with
# --task hopper, on Hopper-v5 at MuJoCo scale (deploy/configs/hopper.toml, the paper's config:
# 5000 random steps first, then G = 20, M = 400), wall-clock per env step of
#   1. `mbpo train --mode sequential` with one thread for SAC and the model (the single-process
#      reference of issue 6),
#   2. `mbpo train --mode sequential` with the config's threads (2 + 2),
#   3. `mbpo run --mode pipelined` (all services, default slack, the config's threads),
#   4. with --mbrl-lib: mbrl-lib 0.2.0's MBPO with the same settings (tools/mbrl_lib_mbpo.py,
#      installed into .venv-torch from PyPI, ~5 GB; on Pendulum about 0.5 s per step on a 2-core
#      machine), with MBRL_THREADS torch threads and OMP_WAIT_POLICY (defaults: 1 thread on
#      Pendulum, its faster setting there; 2 threads with OMP_WAIT_POLICY=ACTIVE on Hopper, its
#      faster setting for the model epoch, results/model-bench-vs-mbrl-lib*.json).
# Prints one JSON object per run and the ratios, and writes results/pipeline-speed-<task>.json
# (results/pipeline-speed-<task>-s<SEED>.json for SEED=... other than 0).
#
# "mean" is wall time per env step over steps 501..STEPS on Pendulum (mbrl-lib's mean also holds
# its first model training, a few seconds over ~1000 steps) and 5001..STEPS on Hopper (both hold
# the first model training, on the 5000 random steps), model trainings included, read from
# metrics.csv; "median" is the median single step (model trainings left out). The runs use the
# same seed; model training time depends on the data (early stopping), so runs whose data differ
# (2 and 3 against 1) differ in model-training time too: repeat with other seeds (SEED=...)
# before reading much into a few percent.
#
# Not part of CI (minutes of compute). Run on a quiet machine: these are wall-clock figures, and
# thread pools wait for their slowest thread, so another busy process distorts them badly.
# Usage: bash tools/compare_pipeline_speed.sh [STEPS] [--mbrl-lib] [--task pendulum|hopper]
#   STEPS defaults to 1400 on Pendulum, 8000 on Hopper (3000 steps after the random ones: about
#   19 min for our three runs and 13 for mbrl-lib's on the 2-core Intel VM, 31 in all).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
usage="usage: $0 [STEPS] [--mbrl-lib] [--task pendulum|hopper]"
steps=""
mbrl=0
task=pendulum
while [ $# -gt 0 ]; do
    case "$1" in
        --mbrl-lib) mbrl=1 ;;
        --task)
            [ $# -ge 2 ] || { echo "$usage; --task needs a value" >&2; exit 2; }
            task="$2"
            shift
            ;;
        *[!0-9]* | "") echo "$usage; got '$1'" >&2; exit 2 ;;
        *)
            if [ -n "$steps" ]; then
                echo "$usage; STEPS given twice ($steps, $1)" >&2
                exit 2
            fi
            steps="$1"
            ;;
    esac
    shift
done
# Per task: the config, the default length, where the mean starts (an evaluation row of
# metrics.csv at or after the first model training) and mbrl-lib's random steps (STEPS must be
# those + a whole number of its 250-step epochs, see tools/mbrl_lib_mbpo.py).
case "$task" in
    pendulum) default_steps=1400 start=500 explore=150 mbrl_threads=1 mbrl_wait=PASSIVE ;;
    hopper) default_steps=8000 start=5000 explore=4750 mbrl_threads=2 mbrl_wait=ACTIVE ;;
    *) echo "--task: expected pendulum or hopper, found '$task'" >&2; exit 2 ;;
esac
steps="${steps:-$default_steps}"
if [ "$steps" -le "$start" ] || [ $(((steps - explore) % 250)) -ne 0 ]; then
    echo "STEPS for $task: expected $explore + a multiple of 250, above $start (the mean starts at step $((start + 1))), found $steps" >&2
    exit 2
fi
mbrl_threads="${MBRL_THREADS:-$mbrl_threads}"
mbrl_wait="${OMP_WAIT_POLICY:-$mbrl_wait}"
seed="${SEED:-0}"
cd "$repo"
# The supervisor and the service binaries `mbpo run` starts, with the MuJoCo tasks when MuJoCo
# is set up (deploy/build.sh: a build without them would also take them from the learning
# lanes' binary).
if [ "$task" = hopper ]; then
    bash deploy/setup_mujoco.sh >&2
fi
bash deploy/build.sh pipeline >&2

config="deploy/configs/$task.toml"
out="$(mktemp -d /tmp/pipeline-speed.XXXXXX)"
common=(--config "$config" --steps "$steps" --seed "$seed")
echo "runs in $out" >&2
# One run; on failure, the tail of its log and the exit.
run() {
    local name="$1"
    shift
    "$@" --out "$out/$name" 2>"$out/$name.log" >/dev/null || {
        echo "$name failed; the end of $out/$name.log:" >&2
        tail -n 20 "$out/$name.log" >&2
        exit 1
    }
}
run sequential-1-thread target/release/mbpo train --mode sequential "${common[@]}" \
    --set sac.threads=1 --set model.threads=1
run sequential target/release/mbpo train --mode sequential "${common[@]}"
run pipelined target/release/mbpo run --mode pipelined "${common[@]}" --quiet

mbrl_json="$out/mbrl-lib.json"
if [ "$mbrl" = 1 ]; then
    venv="$repo/.venv-torch"
    [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tools/requirements-torch.txt
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -r tools/requirements-mbrl.txt
    if [ "$task" = hopper ]; then
        "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -r tools/requirements-mujoco.txt
    fi
    OMP_WAIT_POLICY="$mbrl_wait" "$venv/bin/python" tools/mbrl_lib_mbpo.py --task "$task" --steps "$steps" --threads "$mbrl_threads" --seed "$seed" \
        2>"$out/mbrl-lib.log" | tail -1 >"$mbrl_json"
    python3 -c 'import json, sys; json.load(open(sys.argv[1]))["mean_seconds_per_env_step"]' "$mbrl_json" || {
        echo "mbrl-lib gave no result line; the end of $out/mbrl-lib.log:" >&2
        tail -n 20 "$out/mbrl-lib.log" >&2
        exit 1
    }
fi

python3 - "$out" "$steps" "$mbrl_json" "$seed" "$task" "$start" <<'PY'
import csv, glob, json, os, platform, re, sys
out, steps, mbrl_json, seed, task, start = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), sys.argv[5], int(sys.argv[6])
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())

# "model trained for step T on N transitions: E epochs, ..., S s" (the sequential trainer's and
# the model-trainer service's line): early stopping sets the epochs, so they are the work done.
TRAINED = re.compile(r"trained for step (\d+) on \d+ transitions: (\d+) epochs, .*, ([0-9.]+) s")

def model_trainings(run, log):
    """Epochs and seconds of the model trainings at steps start+1..steps, from the run's logs."""
    found = {}
    for path in glob.glob(os.path.join(run, "**", "*.log"), recursive=True) + [log]:
        for line in open(path, errors="replace"):
            m = TRAINED.search(line)
            if m and start < int(m.group(1)) <= steps:
                found[int(m.group(1))] = (int(m.group(2)), float(m.group(3)))
    epochs = sum(e for e, _ in found.values())
    seconds = sum(t for _, t in found.values())
    return {"model_trainings": len(found), "model_epochs": epochs,
            "model_train_seconds": round(seconds, 1),
            "model_seconds_per_epoch": round(seconds / epochs, 4) if epochs else None}

def ours(name):
    run = os.path.join(out, name)
    s = json.load(open(os.path.join(run, "summary.json")))
    if s.get("status") != "completed":
        sys.exit(f"{name}: status {s.get('status')} (see {run}/summary.json)")
    wall = {int(r["env_steps"]): float(r["wall_seconds"]) for r in csv.DictReader(open(os.path.join(run, "metrics.csv")))}
    if start not in wall or steps not in wall:
        sys.exit(f"{name}: metrics.csv has no rows at {start} and {steps} (see the config's eval.every)")
    entry = {
        "run": name,
        "wall_seconds": round(s["wall_seconds"], 1),
        "median_seconds_per_env_step": round(s.get("median_seconds_per_env_step") or float("nan"), 4),
        "mean_seconds_per_env_step": round((wall[steps] - wall[start]) / (steps - start), 4),
        "final_eval_return": round(s["final_eval_return"], 1),
        **model_trainings(run, os.path.join(out, f"{name}.log")),
    }
    if "ipc" in s:
        entry["ipc_share"] = {p: round(v["share"], 4) for p, v in s["ipc"].items()}
        entry["real_transitions_lost"] = s["real_transitions"]["lost"]
    return entry

runs = [ours("sequential-1-thread"), ours("sequential"), ours("pipelined")]
by = {r["run"]: r for r in runs}
if os.path.exists(mbrl_json) and os.path.getsize(mbrl_json) > 0:
    m = json.load(open(mbrl_json))
    # mbrl-lib trains after real step T what ours trains at the start of T + 1 (its docstring).
    fits = [(e, t) for after, e, t in zip(m["model_trained_after_step"], m["model_train_epochs"],
                                          m["model_fit_seconds_each"]) if start <= after < steps]
    epochs, seconds = sum(e for e, _ in fits), sum(t for _, t in fits)
    runs.append({
        "run": "mbrl-lib",
        "median_seconds_per_env_step": round(m["median_single_step_seconds"], 4),
        "mean_seconds_per_env_step": round(m["mean_seconds_per_env_step"], 4),
        "threads": m["threads"],
        "omp_wait_policy": m["omp_wait_policy"],
        "model_trainings": len(fits),
        "model_epochs": epochs,
        "model_train_seconds": round(seconds, 1),
        "model_seconds_per_epoch": round(seconds / epochs, 4) if epochs else None,
    })
    by["mbrl-lib"] = runs[-1]

def ratio(a, b, key):
    return round(by[a][key] / by[b][key], 2)

ratios = {
    "sequential_1_thread_over_pipelined_mean": ratio("sequential-1-thread", "pipelined", "mean_seconds_per_env_step"),
    "sequential_1_thread_over_pipelined_wall": ratio("sequential-1-thread", "pipelined", "wall_seconds"),
    "sequential_over_pipelined_mean": ratio("sequential", "pipelined", "mean_seconds_per_env_step"),
    "sequential_1_thread_over_sequential_mean": ratio("sequential-1-thread", "sequential", "mean_seconds_per_env_step"),
}
if "mbrl-lib" in by:
    ratios["mbrl_lib_over_pipelined_mean"] = ratio("mbrl-lib", "pipelined", "mean_seconds_per_env_step")
    ratios["mbrl_lib_over_pipelined_median"] = ratio("mbrl-lib", "pipelined", "median_seconds_per_env_step")
    if by["mbrl-lib"]["model_seconds_per_epoch"] and by["sequential"]["model_seconds_per_epoch"]:
        # Per model epoch: the same work whatever early stopping decided (a training's epochs
        # cover more transitions as the data grow, in both).
        ratios["mbrl_lib_over_sequential_seconds_per_model_epoch"] = ratio(
            "mbrl-lib", "sequential", "model_seconds_per_epoch")
for r in runs:
    print(json.dumps(r))
print(json.dumps(ratios))
result = {"config": f"deploy/configs/{task}.toml", "steps": steps, "mean_from_step": start + 1,
          "seed": seed, "cpu": cpu, "cores": os.cpu_count(), "runs": runs, "ratios": ratios}
# One file per seed (seed 0 keeps the plain name), so repeats over seeds do not overwrite.
name = f"results/pipeline-speed-{task}.json" if seed == 0 else f"results/pipeline-speed-{task}-s{seed}.json"
json.dump(result, open(name, "w"), indent=2)
print(f"wrote {name}", file=sys.stderr)
PY
