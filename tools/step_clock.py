#!/usr/bin/env python3
"""Step-interval figures of a paced run, by the env's own clock (tools/step_clock_env.py).

    python3 tools/step_clock.py <out> --hz 50 [--role actor|evaluator|all]

Reads `<out>/steps-*.jsonl`, takes the intervals between consecutive steps of one episode
(intervals across a reset are left out: a paced actor may rest there) and prints one JSON
object: how many intervals, and |interval - 1/hz| at p50, p99, p99.9 and max in milliseconds,
with the count of intervals off by more than 0.5 ms, 2 ms and a whole period (a missed step).
"""

import argparse
import glob
import json
import os
import sys


def quantile(sorted_values, q):
    if not sorted_values:
        return None
    i = min(len(sorted_values) - 1, int(q * len(sorted_values)))
    return sorted_values[i]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--hz", type=float, required=True)
    p.add_argument("--role", choices=["actor", "evaluator", "all"], default="actor")
    a = p.parse_args()
    period_ns = 1e9 / a.hz
    errors, intervals, episodes, files = [], [], 0, 0
    for path in sorted(glob.glob(os.path.join(a.out, "steps-*.jsonl"))):
        files += 1
        with open(path) as f:
            for line in f:
                ep = json.loads(line)
                is_eval = "--eval" in ep["process"].split()
                if a.role != "all" and is_eval != (a.role == "evaluator"):
                    continue
                episodes += 1
                t = ep["steps"]
                for t0, t1 in zip(t, t[1:]):
                    intervals.append(t1 - t0)
                    errors.append(abs(t1 - t0 - period_ns) / 1e6)
    if not errors:
        sys.exit(f"{a.out}: no {a.role} intervals in {files} steps-*.jsonl file(s)")
    errors.sort()
    period_ms = period_ns / 1e6
    print(json.dumps({
        "dir": a.out,
        "role": a.role,
        "control_hz": a.hz,
        "episodes": episodes,
        "intervals": len(errors),
        "mean_interval_ms": round(sum(intervals) / len(intervals) / 1e6, 4),
        "error_ms": {
            "p50": round(quantile(errors, 0.5), 4),
            "p99": round(quantile(errors, 0.99), 4),
            "p999": round(quantile(errors, 0.999), 4),
            "max": round(errors[-1], 4),
        },
        "over_0_5_ms": sum(e > 0.5 for e in errors),
        "over_2_ms": sum(e > 2.0 for e in errors),
        "over_a_period": sum(e > period_ms for e in errors),
    }))


if __name__ == "__main__":
    main()
