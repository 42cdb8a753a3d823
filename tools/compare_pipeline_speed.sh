#!/usr/bin/env bash
# MBPO on Pendulum-v1 (deploy/configs/pendulum.toml: G = 20, M = 400, 7 x 4x200), wall-clock per
# env step of
#   1. `mbpo train --mode sequential` with one thread for SAC and the model (the single-process
#      reference of issue 6),
#   2. `mbpo train --mode sequential` with the config's threads (2 + 2),
#   3. `mbpo run --mode pipelined` (all services, default slack, the config's threads),
#   4. with --mbrl-lib: mbrl-lib 0.2.0's MBPO with the same settings (tools/mbrl_lib_pendulum.py,
#      installed into .venv-torch from PyPI, ~5 GB; about 0.7 s per step on a 2-core machine).
# Prints one JSON object per run and the ratios, and writes results/pipeline-speed-pendulum.json
# (results/pipeline-speed-pendulum-s<SEED>.json for SEED=... other than 0).
#
# "mean" is wall time per env step over steps 501..STEPS (model trainings included, read from
# metrics.csv; mbrl-lib's mean also holds its first model training, a few seconds over ~1000
# steps); "median" is the median single step (model trainings left out). The runs use the
# same seed; model training time depends on the data (early stopping), so runs whose data differ
# (2 and 3 against 1) differ in model-training time too: repeat with other seeds (SEED=...)
# before reading much into a few percent.
#
# Not part of CI (minutes of compute). Run on a quiet machine: these are wall-clock figures, and
# thread pools wait for their slowest thread, so another busy process distorts them badly.
# Usage: bash tools/compare_pipeline_speed.sh [STEPS (default 1400)] [--mbrl-lib]
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
steps=""
mbrl=0
for arg in "$@"; do
    case "$arg" in
        --mbrl-lib) mbrl=1 ;;
        *[!0-9]* | "") echo "usage: $0 [STEPS] [--mbrl-lib]; got '$arg'" >&2; exit 2 ;;
        *)
            if [ -n "$steps" ]; then
                echo "usage: $0 [STEPS] [--mbrl-lib]; STEPS given twice ($steps, $arg)" >&2
                exit 2
            fi
            steps="$arg"
            ;;
    esac
done
steps="${steps:-1400}"
if [ "$steps" -le 500 ]; then
    echo "STEPS must be above 500 (the first model training is at step 401; the mean starts at 501)" >&2
    exit 2
fi
seed="${SEED:-0}"
cd "$repo"
cargo build --release --locked --workspace --bins >&2

config=deploy/configs/pendulum.toml
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
    "$venv/bin/python" tools/mbrl_lib_pendulum.py --steps "$steps" --threads 1 --seed "$seed" \
        2>"$out/mbrl-lib.log" | tail -1 >"$mbrl_json"
    python3 -c 'import json, sys; json.load(open(sys.argv[1]))["mean_seconds_per_env_step"]' "$mbrl_json" || {
        echo "mbrl-lib gave no result line; the end of $out/mbrl-lib.log:" >&2
        tail -n 20 "$out/mbrl-lib.log" >&2
        exit 1
    }
fi

python3 - "$out" "$steps" "$mbrl_json" "$seed" <<'PY'
import csv, json, os, platform, sys
out, steps, mbrl_json, seed = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())

def ours(name):
    run = os.path.join(out, name)
    s = json.load(open(os.path.join(run, "summary.json")))
    if s.get("status") != "completed":
        sys.exit(f"{name}: status {s.get('status')} (see {run}/summary.json)")
    wall = {int(r["env_steps"]): float(r["wall_seconds"]) for r in csv.DictReader(open(os.path.join(run, "metrics.csv")))}
    if 500 not in wall or steps not in wall:
        sys.exit(f"{name}: metrics.csv has no rows at 500 and {steps} (evaluation every 250 steps expected)")
    entry = {
        "run": name,
        "wall_seconds": round(s["wall_seconds"], 1),
        "median_seconds_per_env_step": round(s.get("median_seconds_per_env_step") or float("nan"), 4),
        "mean_seconds_per_env_step": round((wall[steps] - wall[500]) / (steps - 500), 4),
        "final_eval_return": round(s["final_eval_return"], 1),
    }
    if "ipc" in s:
        entry["ipc_share"] = {p: round(v["share"], 4) for p, v in s["ipc"].items()}
        entry["real_transitions_lost"] = s["real_transitions"]["lost"]
    return entry

runs = [ours("sequential-1-thread"), ours("sequential"), ours("pipelined")]
by = {r["run"]: r for r in runs}
if os.path.exists(mbrl_json) and os.path.getsize(mbrl_json) > 0:
    m = json.load(open(mbrl_json))
    runs.append({
        "run": "mbrl-lib",
        "median_seconds_per_env_step": round(m["median_single_step_seconds"], 4),
        "mean_seconds_per_env_step": round(m["mean_seconds_per_env_step"], 4),
        "threads": m["threads"],
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
for r in runs:
    print(json.dumps(r))
print(json.dumps(ratios))
result = {"config": "deploy/configs/pendulum.toml", "steps": steps, "seed": seed, "cpu": cpu,
          "cores": os.cpu_count(), "runs": runs, "ratios": ratios}
# One file per seed (seed 0 keeps the plain name), so repeats over seeds do not overwrite.
name = "results/pipeline-speed-pendulum.json" if seed == 0 else f"results/pipeline-speed-pendulum-s{seed}.json"
json.dump(result, open(name, "w"), indent=2)
print(f"wrote {name}", file=sys.stderr)
PY
