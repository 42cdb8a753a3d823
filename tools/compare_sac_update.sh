#!/usr/bin/env bash
# One SAC update (HalfCheetah dims: obs 17, act 6, 2 x 256, batch 256): mbpo against PyTorch on
# this machine, interleaved so both see the same machine state.
#
# 1. a venv with PyTorch at <repo>/.venv-torch (gitignored; tools/requirements-torch.txt, ~5 GB);
# 2. ROUNDS rounds (default 5) per thread count (1 and 2): tools/torch_sac_update.py, then
#    `mbpo bench sac-update`, each a fresh process;
# 3. prints one JSON line per thread count with the medians and mbpo's time as a fraction of
#    PyTorch's, and writes them to results/sac-update-vs-pytorch.json.
#
# Not part of CI (downloads PyTorch). Run on a quiet machine: these are wall-clock figures.
# Usage: bash tools/compare_sac_update.sh [ROUNDS]
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
rounds="${1:-5}"
venv="$repo/.venv-torch"
cd "$repo"

if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tools/requirements-torch.txt
bash deploy/build.sh cli >&2

log="$(mktemp /tmp/sac-update-compare.XXXXXX)"
for threads in 1 2; do
    for _ in $(seq "$rounds"); do
        "$venv/bin/python" tools/torch_sac_update.py --threads "$threads" >>"$log"
        target/release/mbpo bench sac-update --threads "$threads" >>"$log"
    done
done

"$venv/bin/python" - "$log" <<'PY'
import json, statistics, sys, platform
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
out = []
for threads in (1, 2):
    torch_ms = [r["ms_per_update"] for r in rows if r.get("framework") == "pytorch" and r["threads"] == threads]
    ours = [r for r in rows if r.get("bench") == "sac-update" and r["threads"] == threads]
    ours_ms = [r["ms_per_update"] for r in ours]
    entry = {
        "threads": threads,
        "rounds": len(ours_ms),
        "pytorch_ms": statistics.median(torch_ms),
        "pytorch_ms_all": torch_ms,
        "mbpo_ms": round(statistics.median(ours_ms), 3),
        "mbpo_ms_all": [round(x, 3) for x in ours_ms],
        "mbpo_over_pytorch": round(statistics.median(ours_ms) / statistics.median(torch_ms), 3),
        "mbpo_fraction_of_roofline": round(statistics.median(r["fraction_of_roofline"] for r in ours), 3),
        "roofline_gflops": round(statistics.median(r["roofline_gflops"] for r in ours), 1),
        "torch": next(r["torch"] for r in rows if r.get("framework") == "pytorch"),
        "cpu": cpu,
    }
    print(json.dumps(entry))
    out.append(entry)
json.dump(out, open("results/sac-update-vs-pytorch.json", "w"), indent=2)
PY
rm -f "$log"
