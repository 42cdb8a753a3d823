#!/usr/bin/env bash
# What the Python env bridge adds per env step: Gymnasium's own `env.step` loop
# (tools/gym_env_speed.py) against the same env stepped from Rust through the bridge
# (`mbpo bench env --env gym:<id>`, which keeps the bridge and its Python process on one CPU,
# as `mbpo run` does for actors), back to back in one run, then the difference in
# microseconds per step (goal: <= 20 us). Measure on a quiet machine.
#
#   bash deploy/bench_python_bridge.sh [--seconds 3] [ENV_ID ...]    (default: Pendulum-v1,
#   and with MuJoCo set up (deploy/setup_mujoco.sh) also HalfCheetah-v5 and Hopper-v5)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=3
ids=()
while [ $# -gt 0 ]; do
    case "$1" in
        --seconds) seconds="$2"; shift 2 ;;
        *) ids+=("$1"); shift ;;
    esac
done
bash deploy/setup_python.sh >&2
if [ ${#ids[@]} -eq 0 ]; then
    ids=(Pendulum-v1)
    if .venv/bin/python -c "import mujoco" 2>/dev/null; then ids+=(HalfCheetah-v5 Hopper-v5); fi
fi
bash deploy/build.sh cli >&2
echo "load: $(uptime)" >&2
out="$(mktemp)"
trap 'rm -f "$out"' EXIT
for id in "${ids[@]}"; do
    .venv/bin/python tools/gym_env_speed.py --seconds "$seconds" --env "$id" | tee -a "$out"
    ./target/release/mbpo bench env --seconds "$seconds" --env "gym:$id" | tee -a "$out"
done
.venv/bin/python - "$out" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
own = {r["env"]: r["steps_per_sec"] for r in rows if r["impl"] == "gymnasium"}
print(f"{'env':<18} {'gymnasium us/step':>18} {'over bridge us/step':>20} {'added us/step':>14}")
for r in rows:
    if r["impl"] != "gymnasium-over-bridge":
        continue
    env = r["env"].removeprefix("gym:")
    a, b = 1e6 / own[env], 1e6 / r["steps_per_sec"]
    print(f"{env:<18} {a:>18.1f} {b:>20.1f} {b - a:>14.1f}")
PY
