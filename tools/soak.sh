#!/usr/bin/env bash
# Soak: a long pipelined MBPO run on Pendulum-v1 whose every process is sampled for resident
# memory (VmRSS) and open file descriptors, to show that nothing grows without bound (issue 24
# item 9). Prints one JSON line per process (RSS after warm-up and at the end, growth, fds at
# both) and a verdict line, and writes results/soak-<steps>.json plus the samples as CSV.
#
# The run's D_env holds at most `mbpo.replay_capacity` transitions (default here: a fifth of the
# steps, SOAK_CAPACITY overrides it), so every buffer is full well before the end: "after
# warm-up" is the first sample at or past capacity + 10 % of the steps, and any later growth is
# not data but a leak. With the default capacity (1M) the processes that hold D_env (model
# trainer, rollout generator, learner) grow with the data they hold, about 120 B a Pendulum
# transition (the first 100k soak, 2026-11-25, commit 2f68d76): memory bounded by the capacity,
# not a leak in time.
# Not part of CI (minutes). Usage: bash tools/soak.sh [STEPS (default 100000)] [CONFIG]
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
steps="${1:-100000}"
config="${2:-deploy/configs/pendulum-tiny.toml}"
case "$steps" in *[!0-9]* | "") echo "usage: $0 [STEPS] [CONFIG]; STEPS is a number, got '$steps'" >&2; exit 2 ;; esac
capacity="${SOAK_CAPACITY:-$((steps / 5))}"
case "$capacity" in *[!0-9]* | "" | 0) echo "$0: SOAK_CAPACITY is a positive number of transitions, got '$capacity'" >&2; exit 2 ;; esac
[ -f "$config" ] || { echo "$0: no config file $config" >&2; exit 2; }
cargo build --release --locked --workspace --bins >&2
out="$(mktemp -d /tmp/mbpo-soak.XXXXXX)"
run="$out/run"
samples="$out/samples.csv"
echo "soak: $steps steps of $config (D_env capacity $capacity) in $run" >&2
target/release/mbpo run --config "$config" --steps "$steps" --actors 2 --quiet \
    --set checkpoint.every=10000 --set mbpo.replay_capacity="$capacity" --out "$run" >/dev/null 2>"$out/stderr.log" &
launcher=$!
echo "t_seconds,env_steps,process,pid,rss_kib,fds" >"$samples"
started=$(date +%s)
# Sample every 5 s while the launcher lives: each service's newest logged pid.
while kill -0 "$launcher" 2>/dev/null; do
    now=$(($(date +%s) - started))
    t_env=$(ls "$run/checkpoints" 2>/dev/null | grep -E '^[0-9]+$' | sort -n | tail -1 || true)
    t_env=$((10#${t_env:-0}))
    for log in "$run"/logs/*.log; do
        [ -f "$log" ] || continue
        name=$(basename "$log" .log)
        pid=$(grep -o ', pid [0-9]*' "$log" | tail -1 | tr -dc 0-9 || true)
        [ -n "$pid" ] && [ -r "/proc/$pid/status" ] || continue
        rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
        fds=$(ls "/proc/$pid/fd" 2>/dev/null | wc -l)
        [ -n "$rss" ] && echo "$now,$t_env,$name,$pid,$rss,$fds" >>"$samples"
    done
    rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$launcher/status" 2>/dev/null || true)
    fds=$(ls "/proc/$launcher/fd" 2>/dev/null | wc -l)
    [ -n "$rss" ] && echo "$now,$t_env,launcher,$launcher,$rss,$fds" >>"$samples"
    sleep 5
done
wait "$launcher" || { echo "$0: the run failed; see $out/stderr.log" >&2; exit 1; }
python3 - "$samples" "$run" "$steps" "$config" "$capacity" <<'PY'
import csv, json, sys
samples, run, steps, config, capacity = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], int(sys.argv[5])
warm_up = capacity + 0.1 * steps
rows = list(csv.DictReader(open(samples)))
summary = json.load(open(f"{run}/summary.json"))
by = {}
for r in rows:
    by.setdefault(r["process"], []).append(r)
procs = []
for name, rs in sorted(by.items()):
    rs.sort(key=lambda r: int(r["t_seconds"]))
    # The first sample once D_env is full plus 10 % of the steps (env steps are read from the
    # newest checkpoint, every 10k steps).
    after = next((r for r in rs if int(r["env_steps"]) >= warm_up), None)
    if after is None:
        sys.exit(f"soak: no sample of {name} past the warm-up ({warm_up:.0f} env steps); run more steps")
    last = rs[-1]
    a, b = int(after["rss_kib"]), int(last["rss_kib"])
    entry = {"process": name, "samples": len(rs), "rss_mib_after_warm_up": round(a / 1024, 1),
             "rss_mib_end": round(b / 1024, 1), "growth": round(b / a - 1, 4) if a else None,
             "fds_after_warm_up": int(after["fds"]), "fds_end": int(last["fds"]),
             "rss_mib_max": round(max(int(r["rss_kib"]) for r in rs) / 1024, 1)}
    procs.append(entry)
    print(json.dumps(entry))
worst = max((p["growth"] or 0) for p in procs)
fd_growth = max(p["fds_end"] - p["fds_after_warm_up"] for p in procs)
verdict = {"steps": steps, "config": config, "replay_capacity": capacity,
           "warm_up_env_steps": int(warm_up), "status": summary["status"],
           "wall_seconds": round(summary["wall_seconds"], 1), "lost": summary["real_transitions"]["lost"],
           "largest_rss_growth_after_warm_up": worst, "largest_fd_growth": fd_growth,
           "holds": worst <= 0.05 and fd_growth <= 0}
print(json.dumps(verdict))
json.dump({"processes": procs, "verdict": verdict}, open(f"results/soak-{steps}.json", "w"), indent=2)
PY
cp "$samples" "results/soak-$steps-samples.csv"
