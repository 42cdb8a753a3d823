#!/usr/bin/env python3
"""The peer rows of results/RESULTS.md's peer table (issue 60), from the published files.

    python3 tools/peer_table.py path/to/SimbaV2/results/baseline [--budgets 50000,100000,300000]

Reads the SimbaV2 authors' collection of Gym v4 baselines (dojeon-ai/SimbaV2 results/baseline,
columns exp_name, env_name, seed, metric, env_step, value) and prints one markdown row per
method: mean ± std (n - 1) over its seeds at each budget, for Hopper, Walker2d, HalfCheetah,
Ant and Humanoid. A seed's value at a budget is its last evaluation at or before it and at most
1 % before (SAC's 99,996 is its 100k) -- the rule of `mbpo plot --peer` (common/report/src/
peer_curve.rs, Reading::AtPoints); "–" where a seed has none. Only the standard library.
"""
import argparse
import collections
import csv
import os
import statistics

METHODS = [
    ("SAC", "sac.csv"),
    ("REDQ, UTD 20", "redq_utd20.csv"),
    ("DroQ, UTD 20", "droq_utd20.csv"),
    ("CrossQ", "crossq.csv"),
    ("MR.Q", "mrq.csv"),
    ("BRO, UTD 10", "bro_utd10.csv"),
    ("SimbaV2, UTD 8", "simbaV2_utd8.csv"),
]
TASKS = ["Hopper", "Walker2d", "HalfCheetah", "Ant", "Humanoid"]


def seeds_of(rows, task):
    """Per seed, the (env steps, return) evaluations of the v4 task (either spelling)."""
    seeds = collections.defaultdict(list)
    for r in rows:
        env = r["env_name"].replace("_", "-")
        if r["metric"] == "avg_return" and env == f"{task}-v4":
            seeds[r["seed"]].append((round(float(r["env_step"])), float(r["value"])))
    return seeds


def cell(seeds, budget):
    values = []
    for points in seeds.values():
        near = [v for step, v in sorted(points) if budget - budget // 100 <= step <= budget]
        if not near:
            return "–"
        values.append(near[-1])
    if len(values) < 2:
        return "–"
    return f"{statistics.mean(values):.0f} ± {statistics.stdev(values):.0f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("baseline_dir")
    parser.add_argument("--budgets", default="50000,100000,300000")
    args = parser.parse_args()
    budgets = [int(b) for b in args.budgets.split(",")]
    for label, name in METHODS:
        with open(os.path.join(args.baseline_dir, name), newline="") as f:
            rows = list(csv.DictReader(f))
        cells, counts = [], set()
        for task in TASKS:
            seeds = seeds_of(rows, task)
            counts.add(len(seeds))
            cells.append(" / ".join(cell(seeds, b) for b in budgets))
        n = "/".join(str(c) for c in sorted(counts))
        print(f"| {label} ({n}) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
