#!/usr/bin/env bash
# Remote vs local actors over a real link (issue 21's benchmark), as root: two network
# namespaces joined by a veth pair (10.77.250.1/.2), each with its own /dev/shm.
#   tools/bench_multihost.sh [config] [steps] [bin dir]
# Runs pipelined MBPO four ways and prints one JSON line each (also appended to
# results/multihost-bench.jsonl): 1 local actor; 0 local + 1 remote; 1 local + 2 remote;
# 3 local. Figures: env steps per second of the whole run (wall) and in steady state (first to
# last metrics row, i.e. without start-up and join), the summary's lost count,
# and the worker's weight latency (learner publish -> worker's shared memory, p50/p99 ms; one
# machine, so one clock). Measure on a quiet machine.
set -euo pipefail
cd "$(dirname "$0")/.."
CONFIG=${1:-deploy/configs/pendulum-tiny.toml}
STEPS=${2:-3000}
BIN=${3:-target/release}
[ "$(id -u)" = 0 ] || { echo "needs root (network namespaces)" >&2; exit 2; }
[ -x "$BIN/mbpo-gateway" ] || cargo build --release --locked -p mbpo -p mbpo-gateway -p mbpo-actor -p mbpo-model-trainer -p mbpo-rollout-generator -p mbpo-sac-learner
BIN=$(cd "$BIN" && pwd)
H=mbbench-h; W=mbbench-w
cleanup() { ip netns del $H 2>/dev/null || true; ip netns del $W 2>/dev/null || true; }
trap cleanup EXIT
cleanup
ip netns add $H; ip netns add $W
ip link add mbbench-vh type veth peer name mbbench-vw
ip link set mbbench-vh netns $H; ip link set mbbench-vw netns $W
ip -n $H addr add 10.77.250.1/24 dev mbbench-vh; ip -n $W addr add 10.77.250.2/24 dev mbbench-vw
for n in $H $W; do ip -n $n link set lo up; done
ip -n $H link set mbbench-vh up; ip -n $W link set mbbench-vw up
TMP=$(mktemp -d /tmp/mbbench.XXXX)
printf 'mbpo:bench-%s\n' "$RANDOM$RANDOM" > "$TMP/password"
mkdir -p "$TMP/creds" && cp "$TMP/password" "$TMP/creds/password"
inns() { local ns=$1; shift; ip netns exec "$ns" sh -c 'mount -t tmpfs mbpo-shm /dev/shm && exec "$0" "$@"' "$@"; }
mkdir -p results
one() { # name local remote
    local name=$1 local=$2 remote=$3 out="$TMP/$1"
    local args=(run --config "$CONFIG" --steps "$STEPS" --mode pipelined --actors "$local" --out "$out" --ipc-root /tmp/mbb-h --quiet)
    local wpid=""
    if [ "$remote" -gt 0 ]; then
        args+=(--listen tcp/10.77.250.1:7447 --remote-actors "$remote" --credentials "$TMP/creds")
        inns $W "$BIN/mbpo" join tcp/10.77.250.1:7447 --actors "$remote" --credentials "$TMP/creds" \
            --ipc-root /tmp/mbb-w --dir "$TMP/work-$name" > "$TMP/$name.worker.json" 2> "$TMP/$name.worker.log" &
        wpid=$!
    fi
    inns $H "$BIN/mbpo" "${args[@]}" > /dev/null 2> "$TMP/$name.head.log"
    [ -n "$wpid" ] && wait "$wpid"
    python3 - "$name" "$out/summary.json" "$TMP/$name.worker.json" "$STEPS" "$CONFIG" <<'PY' | tee -a results/multihost-bench.jsonl
import json, sys, os
name, summary, worker, steps, config = sys.argv[1:]
s = json.load(open(summary))
w = {}
if os.path.exists(worker) and os.path.getsize(worker) > 0:
    w = json.loads(open(worker).read().strip().splitlines()[-1])
# Steady state: from the first metrics row (the first evaluation, after start-up and the
# workers' join) to the last.
import csv
rows = list(csv.DictReader(open(os.path.join(os.path.dirname(summary), "metrics.csv"))))
(t0, s0), (t1, s1) = [(float(r["wall_seconds"]), int(r["env_steps"])) for r in (rows[0], rows[-1])]
print(json.dumps({
    "setup": name, "config": config, "steps": int(steps), "status": s["status"],
    "wall_seconds": round(s["wall_seconds"], 2),
    "env_steps_per_second": round(int(steps) / s["wall_seconds"], 1),
    "steady_env_steps_per_second": round((s1 - s0) / (t1 - t0), 1) if t1 > t0 else None,
    "lost": s["real_transitions"]["lost"],
    "weights_latency_ms_p50": w.get("weights_latency_ms_p50"),
    "weights_latency_ms_p99": w.get("weights_latency_ms_p99"),
    "weights_applied": w.get("weights_applied"),
}))
PY
}
one local-1 1 0
one remote-1 0 1
one local-1+remote-2 1 2
one local-3 3 0
rm -rf "$TMP"
