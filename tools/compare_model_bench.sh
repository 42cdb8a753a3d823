#!/usr/bin/env bash
# The dynamics model's two hot paths, ours against mbrl-lib 0.2.0 on PyTorch, on this machine,
# interleaved so both see the same machine state: one training epoch over 10k transitions and
# 100k one-step rollouts (7 x 4x200 SiLU, HalfCheetah dims; `mbpo bench model-train` and
# `mbpo bench model-rollout` against tools/mbrl_lib_model_bench.py).
#
# 1. a venv with PyTorch and mbrl-lib at <repo>/.venv-torch (gitignored; ~5 GB;
#    tools/requirements-torch.txt, tools/requirements-mbrl.txt);
# 2. ROUNDS rounds (default 5) per thread count (1 and 2), each program a fresh process; at
#    2 threads PyTorch runs twice, with OMP_WAIT_POLICY=PASSIVE and ACTIVE (spinning threads
#    can be faster on a quiet machine), and the faster one is compared;
# 3. prints one JSON line per thread count with the medians of each round's best and ours as a
#    fraction of mbrl-lib's, and writes them to results/model-bench-vs-mbrl-lib.json.
#
# Not part of CI (downloads PyTorch). Run on a quiet machine: these are wall-clock figures.
# Usage: bash tools/compare_model_bench.sh [ROUNDS]
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
rounds="${1:-5}"
case "$rounds" in
    '' | *[!0-9]* | 0) echo "usage: $0 [ROUNDS]; ROUNDS must be a positive integer, got '$rounds'" >&2; exit 2 ;;
esac
venv="$repo/.venv-torch"
cd "$repo"

[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tools/requirements-torch.txt
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -r tools/requirements-mbrl.txt
bash deploy/build.sh cli >&2

log="$(mktemp /tmp/model-bench-compare.XXXXXX)"
for threads in 1 2; do
    for _ in $(seq "$rounds"); do
        policies=PASSIVE
        [ "$threads" = 2 ] && policies="PASSIVE ACTIVE"
        for policy in $policies; do
            OMP_WAIT_POLICY=$policy "$venv/bin/python" tools/mbrl_lib_model_bench.py \
                --threads "$threads" >>"$log"
        done
        target/release/mbpo bench model-train --threads "$threads" >>"$log"
        target/release/mbpo bench model-rollout --threads "$threads" >>"$log"
    done
done

"$venv/bin/python" - "$log" <<'PY'
import json, statistics, sys, platform
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
med = statistics.median
out = []
for threads in (1, 2):
    theirs = [r for r in rows if r.get("framework") == "mbrl-lib" and r["threads"] == threads]
    by_policy = {}
    for r in theirs:
        by_policy.setdefault(r["omp_wait_policy"], []).append(r)
    # The policy with the faster median epoch is mbrl-lib's figure.
    policy, best = min(by_policy.items(), key=lambda kv: med(r["epoch_seconds"] for r in kv[1]))
    train = [r for r in rows if r.get("bench") == "model-train" and r["threads"] == threads]
    roll = [r for r in rows if r.get("bench") == "model-rollout" and r["threads"] == threads]
    epoch_theirs = med(r["epoch_seconds"] for r in best)
    epoch_ours = med(r["seconds"] for r in train)
    roll_theirs = med(r["rollout_seconds"] for r in best)
    roll_ours = med(r["seconds"] for r in roll)
    entry = {
        "threads": threads,
        "rounds": len(train),
        "epoch_seconds_mbrl_lib": round(epoch_theirs, 4),
        "epoch_seconds_mbrl_lib_all": {p: [round(r["epoch_seconds"], 4) for r in rs] for p, rs in by_policy.items()},
        "train_call_seconds_mbrl_lib": round(med(r["train_call_seconds"] for r in best), 4),
        "epoch_seconds_mbpo": round(epoch_ours, 4),
        "epoch_seconds_mbpo_all": [round(r["seconds"], 4) for r in train],
        "epoch_mbpo_over_mbrl_lib": round(epoch_ours / epoch_theirs, 3),
        "epoch_mbpo_fraction_of_roofline": round(med(r["fraction_of_roofline"] for r in train), 3),
        "rollout_seconds_mbrl_lib": round(roll_theirs, 4),
        "rollout_seconds_mbrl_lib_all": {p: [round(r["rollout_seconds"], 4) for r in rs] for p, rs in by_policy.items()},
        "rollout_seconds_mbpo": round(roll_ours, 4),
        "rollout_seconds_mbpo_all": [round(r["seconds"], 4) for r in roll],
        "rollout_mbpo_over_mbrl_lib": round(roll_ours / roll_theirs, 3),
        "mbrl_lib_omp_wait_policy": policy,
        "roofline_gflops": round(med(r["roofline_gflops"] for r in train), 1),
        "torch": best[0]["torch"],
        "mbrl": best[0]["mbrl"],
        "cpu": cpu,
    }
    print(json.dumps(entry))
    out.append(entry)
json.dump(out, open("results/model-bench-vs-mbrl-lib.json", "w"), indent=2)
PY
rm -f "$log"
