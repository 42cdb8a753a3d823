"""Read the TensorBoard event files of mbpo run directories with TensorBoard itself.

Usage: check_tensorboard.py RUN_DIR [RUN_DIR ...] [--resumed RUN_DIR]

For each run directory, every scalar in <run>/tb/ is loaded with TensorBoard's own readers
(event_accumulator, the classic API, and plugin_event_accumulator, the one the TensorBoard
server uses) and compared with metrics.csv: every non-empty cell must appear under its tag at
its env step with the same value (as float32), and nothing else may. For --resumed (a run
directory written by `cargo run -p mbpo-train --example tb_resume_fixture`), the same comparison
shows that the restart marker made TensorBoard drop the first run's points after the resume
step. Prints one line per run and exits non-zero on any mismatch.
"""

import csv
import math
import struct
import sys
from pathlib import Path

from tensorboard.backend.event_processing import event_accumulator, plugin_event_accumulator
from tensorboard.util import tensor_util

# Must match TENSORBOARD_TAGS in common/rundir/src/run_dir.rs.
TAGS = {
    "episodes": "train/episodes",
    "eval_return": "eval/return",
    "train_return": "train/return",
    "sac_updates": "sac/updates",
    "critic_loss": "sac/critic_loss",
    "actor_loss": "sac/actor_loss",
    "alpha": "sac/alpha",
    "entropy": "sac/entropy",
    "q_mean": "sac/q_mean",
    "model_holdout_mse": "model/holdout_mse",
    "rollout_length": "model/rollout_length",
    "model_buffer": "model/buffer",
    "wall_seconds": "speed/wall_seconds",
    "env_steps_per_sec": "speed/env_steps_per_sec",
    "updates_per_sec": "speed/updates_per_sec",
    "consistency_loss": "world_model/consistency_loss",
    "reward_loss": "world_model/reward_loss",
}


def f32(x):
    return struct.unpack("<f", struct.pack("<f", float(x)))[0]


def expected(run):
    """{tag: [(step, float32 value)]} from metrics.csv (float32, as the writer stores them)."""
    want = {}
    with open(run / "metrics.csv", newline="") as f:
        for row in csv.DictReader(f):
            step = int(row["env_steps"])
            for column, tag in TAGS.items():
                if row.get(column, "") != "":
                    want.setdefault(tag, []).append((step, f32(row[column])))
    return want


def close(a, b, column_tag):
    # Rounded columns (wall_seconds %.3f, rates %.1f) were rounded in the csv, not in the event.
    if column_tag.startswith("speed/"):
        return math.isclose(a, b, rel_tol=1e-3, abs_tol=0.06)
    return a == b


def compare(name, want, got):
    errors = []
    for tag in sorted(set(want) | set(got)):
        w, g = want.get(tag, []), got.get(tag, [])
        if [s for s, _ in w] != [s for s, _ in g]:
            errors.append(f"{name}: {tag}: steps {[s for s, _ in g]} != metrics.csv {[s for s, _ in w]}")
            continue
        for (s, a), (_, b) in zip(w, g):
            if not close(a, b, tag):
                errors.append(f"{name}: {tag} at step {s}: {b} != metrics.csv {a}")
    return errors


def read_classic(tb):
    acc = event_accumulator.EventAccumulator(str(tb), size_guidance={event_accumulator.SCALARS: 0})
    acc.Reload()
    return {t: [(e.step, e.value) for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]}


def read_server(tb):
    acc = plugin_event_accumulator.EventAccumulator(str(tb), size_guidance={"tensors": 0})
    acc.Reload()
    out = {}
    for tag in acc.Tags()["tensors"]:
        out[tag] = [(e.step, float(tensor_util.make_ndarray(e.tensor_proto))) for e in acc.Tensors(tag)]
    return out


def check(run):
    tb = run / "tb"
    files = sorted(p.name for p in tb.iterdir())
    want = expected(run)
    errors = []
    for reader, read in (("event_accumulator", read_classic), ("plugin_event_accumulator", read_server)):
        errors += compare(f"{run} [{reader}]", want, read(tb))
    points = sum(len(v) for v in want.values())
    status = "ok" if not errors else f"{len(errors)} MISMATCH(ES)"
    print(f"{run}: {len(files)} event file(s), {len(want)} tags, {points} points, both readers: {status}")
    for e in errors:
        print("  " + e)
    return errors


def main(argv):
    runs, resumed = [], []
    it = iter(argv)
    for a in it:
        if a == "--resumed":
            resumed.append(Path(next(it)))
        else:
            runs.append(Path(a))
    if not runs and not resumed:
        print(__doc__)
        return 2
    errors = []
    for run in runs + resumed:
        errors += check(run)
    for run in resumed:
        # metrics.csv of the fixture: first run up to 300 (negative returns), resumed run after.
        got = read_classic(run / "tb")["eval/return"]
        want = [(100, -100.0), (200, -200.0), (300, -300.0), (400, 400.0), (500, 500.0), (600, 600.0)]
        if got != want:
            errors.append(f"{run}: eval/return after resume {got} != {want}")
        print(f"{run}: eval/return across the resume: {got}")
    if errors:
        print(f"FAILED: {len(errors)} mismatch(es)")
        return 1
    print("all event files read back by TensorBoard equal metrics.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
