#!/usr/bin/env python3
"""The real-time acting goals, measured. Each case is one `mbpo run` (or `mbpo train`) of MBPO
on Pendulum (deploy/configs/pendulum.toml); its figures go to stdout as one JSON line and into
results/realtime-goals.json with the commit, date and machine (a rerun replaces the case's row).

    python3 tools/bench_realtime_goals.py [CASE ...]   # default: every case, in this order

Cases:
  env-clock-50hz  10k steps at 50 Hz with a Python env (Gymnasium's Pendulum-v1 through
                  tools/step_clock_env.py, which records time.monotonic_ns() at each step):
                  |interval - 20 ms| by the env's own clock, intervals across a reset left out.
                  The learner, model trainer and rollout generator learn on the other core all
                  along (`catch_up = "never"`, G = 2: the updates it owes when the actor
                  is done are few).
  builtin-500hz   50k steps at 500 Hz with the built-in Pendulum (`catch_up = "never"`, G = 1, a
                  model every 25000 steps of at most 50 epochs): the actor's own figures.
  sequential      `mbpo train`, 3000 steps: the reference of the next three.
  paced-50hz      50 Hz, `catch_up = "between_episodes"`, 3000 steps: env steps to -200.
  never-50hz      50 Hz, `catch_up = "never"`, 3000 steps: wall-clock to -200.
  slow-env        unpaced pipelined, 3000 steps, `actor.env_step_ms` = the sequential run's
                  wall-clock per step, one evaluation at the end (the evaluator's env is slow
                  too): the learner's seconds per step against max(env, learning).
Checkpoints are written only at the end (`checkpoint.every = 0`): a barrier pauses a paced actor,
which then starts a new grid, as after a rest between episodes. Stop other work on the machine
first (the learning lanes: `kill -STOP -- -<pgid>`).
"""

import csv
import json
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MBPO = os.path.join(ROOT, "target/release/mbpo")
OUT = os.path.join(ROOT, "runs/realtime-goals")
RESULTS = os.path.join(ROOT, "results/realtime-goals.json")
CONFIG = "deploy/configs/pendulum.toml"
STEPS = 3000
CASES = ["env-clock-50hz", "builtin-500hz", "sequential", "paced-50hz", "never-50hz", "slow-env"]


def mbpo(command, case, steps, *sets, extra=()):
    out = os.path.join(OUT, case)
    args = [MBPO, command, "--config", CONFIG, "--out", out, "--steps", str(steps),
            "--overwrite", "--set", "checkpoint.every=0", *extra]
    for s in sets:
        args += ["--set", s]
    if command == "run":
        args += ["--quiet"]
    print(" ".join(args), file=sys.stderr)
    subprocess.run(args, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    return out


def figures(run_dir):
    """What a run's summary and metrics say: status, wall-clock, target, pacing, ratios."""
    s = json.load(open(os.path.join(run_dir, "summary.json")))
    inner = s.get("summary", s)
    rows = list(csv.DictReader(open(os.path.join(run_dir, "metrics.csv"))))
    target = inner.get("target_return")
    hit = next((r for r in rows if r["eval_return"] and target is not None
                and float(r["eval_return"]) >= target), None)
    ratios = s.get("ratios") or {}
    return {
        "run": os.path.relpath(run_dir, ROOT),
        "status": inner.get("status"),
        "env_steps": inner.get("env_steps"),
        "wall_seconds": round(inner.get("wall_seconds", 0.0), 1),
        "target_return": target,
        "env_steps_to_target": inner.get("env_steps_to_target"),
        "wall_seconds_to_target": None if hit is None else round(float(hit["wall_seconds"]), 1),
        "final_eval_return": inner.get("final_eval_return"),
        "sac_updates": inner.get("sac_updates"),
        "pacing": s.get("pacing"),
        "ratios": {k: v for k, v in ratios.items() if "updates_per_env_step" in k},
    }


def record(case, row):
    row = {"case": case, **row}
    row["commit"] = git("rev-parse", "--short", "HEAD")
    row["date"] = subprocess.run(["date", "-u", "+%Y-%m-%d"], capture_output=True,
                                 text=True).stdout.strip()
    doc = json.load(open(RESULTS)) if os.path.exists(RESULTS) else {"rows": []}
    with open("/proc/cpuinfo") as f:
        doc["machine"] = next((l.split(":", 1)[1].strip() for l in f
                               if l.startswith("model name")), "?")
    doc["cores"] = os.cpu_count()
    doc["rows"] = [r for r in doc["rows"] if r["case"] != case] + [row]
    with open(RESULTS, "w") as f:
        f.write(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(row), flush=True)


def git(*args):
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def row_of(case):
    doc = json.load(open(RESULTS)) if os.path.exists(RESULTS) else {"rows": []}
    return next((r for r in doc["rows"] if r["case"] == case), None)


def env_clock_50hz(case):
    clock = os.path.join(OUT, case + ".clock")
    subprocess.run(["rm", "-rf", clock], check=True)
    tools = os.path.join(ROOT, "tools")
    run = mbpo("run", case, 10_000, 'env="gym:step_clock_env:make"', f'gym.path=["{tools}"]',
               f'gym.kwargs={{env_id="Pendulum-v1", out="{clock}"}}', 'actor.catch_up="never"',
               "mbpo.updates_per_step=2", "eval.every=1000", extra=["--control-hz", "50"])
    env = subprocess.run([sys.executable, os.path.join(tools, "step_clock.py"), clock, "--hz", "50"],
                         capture_output=True, text=True, check=True).stdout
    return {**figures(run), "env_clock": json.loads(env)}


def builtin_500hz(case):
    run = mbpo("run", case, 50_000, 'actor.catch_up="never"', "mbpo.updates_per_step=1",
               "mbpo.model_train_freq=25000", "model.max_epochs=50", "eval.every=25000",
               extra=["--control-hz", "500"])
    return figures(run)


def sequential(case):
    return figures(mbpo("train", case, STEPS))


def paced_50hz(case):
    return figures(mbpo("run", case, STEPS, extra=["--control-hz", "50"]))


def never_50hz(case):
    row = figures(mbpo("run", case, STEPS, 'actor.catch_up="never"', extra=["--control-hz", "50"]))
    seq = row_of("sequential")
    if seq and seq["wall_seconds_to_target"] and row["wall_seconds_to_target"]:
        row["wall_to_target_vs_sequential"] = round(
            row["wall_seconds_to_target"] / seq["wall_seconds_to_target"], 3)
    return row


def slow_env(case):
    seq = row_of("sequential")
    if seq is None:
        sys.exit("slow-env needs the sequential case's row first")
    return slow_env_figures(seq, mbpo("run", case, STEPS, f"actor.env_step_ms={env_ms(seq)}",
                                      f"eval.every={STEPS}"))


def env_ms(seq):
    """The slow env's step: the sequential run's wall-clock per env step."""
    return round(1000.0 * seq["wall_seconds"] / seq["env_steps"], 1)


def slow_env_figures(seq, run):
    """The overlap of a slowed env with learning: the learner's own seconds from its start to
    its last update (the evaluator steps the slowed env too, one evaluation of 5 episodes at
    the end, which is left out) per env step, against max(env, learning) per step -- over all
    steps, and piecewise: the warm-up's steps have no learning to overlap."""
    row = figures(run)
    log = open(os.path.join(run, "logs/learner.log")).read()
    learner_s = float(re.findall(r"of ([0-9.]+) s in IPC calls", log)[-1])
    cfg = open(os.path.join(run, "config.toml")).read()
    warm = int(re.search(r"init_random_steps = (\d+)", cfg).group(1))
    steps, env = row["env_steps"], env_ms(seq)
    learning = 1000.0 * seq["wall_seconds"] / (steps - warm)
    per_step = 1000.0 * learner_s / steps
    piecewise = (warm * env + (steps - warm) * max(env, learning)) / steps
    row.update({
        "env_step_ms": env,
        "learning_ms_per_learning_step": round(learning, 2),
        "learner_seconds": learner_s,
        "ms_per_step": round(per_step, 2),
        "vs_max_env_learning": round(per_step / max(env, 1000.0 * seq["wall_seconds"] / steps), 3),
        "vs_piecewise_perfect_overlap": round(per_step / piecewise, 3),
        "vs_sequential_with_the_env": round(per_step / (env + 1000.0 * seq["wall_seconds"] / steps), 3),
    })
    return row


def main():
    cases = sys.argv[1:] or CASES
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        sys.exit(f"unknown case(s) {unknown}: the cases are {CASES}")
    subprocess.run(["bash", "deploy/build.sh", "pipeline"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    subprocess.run(["bash", "deploy/setup_python.sh"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    os.makedirs(OUT, exist_ok=True)
    for case in cases:
        record(case, globals()[case.replace("-", "_")](case))


if __name__ == "__main__":
    main()
