#!/usr/bin/env bash
# Side-by-side speed of two builds of the project on one machine (a refactor must not slow
# anything down): the micro-benchmarks, then `mbpo train --mode sequential` (1400 steps),
# `mbpo run --mode lockstep` (900 steps; deterministic, so both builds train on the same data)
# and `mbpo run --mode pipelined` (1400 steps) on deploy/configs/pendulum.toml, seed 0.
# BEFORE and AFTER are directories holding `mbpo` and the four service binaries of a release
# build (e.g. `git worktree add /tmp/base <rev>`, build it, copy target/release/mbpo*).
# Prints one JSON line per micro-benchmark and one line per run (wall, median, mean per step
# over 501..steps, policy hash, model-training epochs and seconds). About 25 minutes; run on a
# quiet machine. Pipelined runs see different data, so their model trainings differ (early
# stopping): compare epochs and seconds per epoch, or lockstep.
# Usage: bash tools/compare_builds.sh BEFORE_DIR AFTER_DIR
set -euo pipefail
[ $# -eq 2 ] || { echo "usage: $0 BEFORE_DIR AFTER_DIR" >&2; exit 2; }
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
config=deploy/configs/pendulum.toml
out="$(mktemp -d /tmp/compare-builds.XXXXXX)"
echo "runs in $out" >&2
declare -A dir=([before]="$1" [after]="$2")
for round in 1 2; do
    for v in before after; do
        b="${dir[$v]}"
        echo "$v round $round: $("$b/mbpo" bench sac-update --threads 2 --seconds 3 2>/dev/null | tail -1)"
        echo "$v round $round: $("$b/mbpo" bench model-train --threads 2 2>/dev/null | tail -1)"
        echo "$v round $round: $("$b/mbpo" bench model-rollout 2>/dev/null | tail -1)"
    done
done
for v in before after; do
    b="${dir[$v]}"
    common=(--config "$config" --seed 0 --out)
    "$b/mbpo" train --mode sequential --steps 1400 "${common[@]}" "$out/seq-$v" >/dev/null 2>"$out/seq-$v.log"
    "$b/mbpo" run --mode lockstep --steps 900 --quiet "${common[@]}" "$out/lock-$v" >/dev/null 2>"$out/lock-$v.log"
    "$b/mbpo" run --mode pipelined --steps 1400 --quiet "${common[@]}" "$out/pipe-$v" >/dev/null 2>"$out/pipe-$v.log"
done
for run in seq lock pipe; do
    for v in before after; do
        python3 - "$out/$run-$v" <<'PY'
import csv, json, re, sys
from pathlib import Path
d = Path(sys.argv[1])
s = json.loads((d / "summary.json").read_text())
w = {int(r["env_steps"]): float(r["wall_seconds"]) for r in csv.DictReader(open(d / "metrics.csv"))}
last = max(w)
mean = (w[last] - w[500]) / (last - 500) if 500 in w else float("nan")
logs = [d / "logs" / "model-trainer.log", d / "logs" / "train.log"]
text = "".join(p.read_text() for p in logs if p.exists())
trained = re.findall(r"trained for step \d+ on \d+ transitions: (\d+) epochs.*?([\d.]+) s$", text, re.M)
epochs = sum(int(e) for e, _ in trained)
secs = sum(float(t) for _, t in trained)
print(f"{d.name}: wall {s.get('wall_seconds', 0):.1f} s, median {s.get('median_seconds_per_env_step')}, "
      f"mean 501..{last} {mean:.4f} s, sha {s.get('policy_sha256', '')[:12]}, "
      f"model trainings {epochs} epochs in {secs:.1f} s (pipeline logs only)")
PY
    done
done
