#!/usr/bin/env bash
# Keep long benchmark runs across fresh checkouts (issue 23's learning lanes run for days).
#
# results/runs/ is not in git: a run directory holds checkpoints of tens of MB, rewritten every
# 1000 env steps. A new checkout of the repository therefore starts without it (a fresh checkout
# on 2026-11-26 found it gone: 5 seeds, about 30 core-hours, and every curve behind the README's
# per-seed figures; results/measurements.md, "Runs lost to a fresh checkout", commit 2685774).
#
#   bash deploy/park_runs.sh [--with-checkpoints]
#       pack results/runs/<run>/ into results/parked/runs/<run>/ (and results/<variant>/runs/<run>/,
#       a benchmark's --out, into results/parked/<variant>/runs/<run>/)
#   bash deploy/park_runs.sh --restore
#       unpack every parked run whose run directory does not exist
#
# A parked run is what `mbpo bench learning` and `mbpo plot` read: config.toml, metrics.csv,
# summary.json and policy.ckpt (once completed) and logs/train.log (gzip; `bench breakdown` reads
# its trainings from it). So a completed seed is reused, never rerun, and its curve is in git. A
# seed under way restored without a checkpoint starts again from step 0 (and, deterministic,
# retraces its parked curve).
#
# --with-checkpoints also packs each unfinished run's newest complete checkpoint
# (checkpoint.tar.zst, zstd -19 --long=27), so the benchmark continues it exactly where it was. It is not
# the default because its floats barely compress. `mbpo train` now stores the model buffer as
# the rollout branches that made it (common/train/src/d_model_branches.rs), so a checkpoint no
# longer grows with the rollout length: Ant-v5 at 32k is 65 MB, 47 MB packed (143 MB at 28k with the rows;
# before that format: 37 MB packed for Hopper at 11,000, 51 MB for Walker2d at 13,000, about
# 100 MB for Hopper near 50k). The rest is three copies of D_env and the models with their Adam
# moments. The copies of D_env are identical bytes in three files, so the packing uses zstd's
# long-distance matching with a 128 MB window (--long=27), which finds the second and third copy:
# Ant-v5 at 45,348 (73 MB) packs to 36 MB instead of 56 MB. The window is zstd's default
# decoding limit, so any zstd >= 1.3.2 unpacks it without options. A checkpoint below 5000 env
# steps is not packed (it saves less than an hour of a core). The learning lanes park with
# checkpoints when they stop: on 2026-12-06 a fresh checkout found the lanes parked with curves
# only, and Hopper seeds at 55k went back to 20k, a TD-MPC2 seed at 60k to 0. The TensorBoard
# file and the older checkpoints (the `checkpoint.keep_every` ones `bench breakdown`/`diagnose`
# start from) are never parked.
#
# A checkpoint parked before at the same step is kept as it is (no second packing: a run restored
# from it, or parked by another script that stopped at the same time; parks run one at a time).
# Parking without --with-checkpoints keeps a checkpoint parked before (older than the run, it
# still saves its steps; a completed run drops it). Restoring never touches a run directory that
# exists: the live one is always at least as new.
# Commit results/parked/ after parking; `deploy/learning_mujoco.sh` parks (curves only) when it
# stops and restores when it starts.
set -euo pipefail
cd "$(dirname "$0")/.."
parked=results/parked

# The newest checkpoint directory holding COMPLETE (checkpoint::latest's rule), or nothing.
newest_complete() {
    local dir
    for dir in $(ls -1d "$1"/checkpoints/*/ 2>/dev/null | sort -r); do
        if [ -f "$dir/COMPLETE" ]; then
            echo "${dir%/}"
            return
        fi
    done
}

# The env steps (directory name) of the checkpoint parked in $1, or nothing.
parked_step() {
    if [ -f "$1/checkpoint.tar.zst" ]; then
        zstd -d --long=27 -q -c "$1/checkpoint.tar.zst" | tar -t 2>/dev/null | head -n 1 |
            cut -d/ -f1 || true
    fi
}

completed() {
    [ -f "$1/summary.json" ] && grep -q '"status": *"completed"' "$1/summary.json"
}

park() {
    local run=$1 dest ckpt file
    dest=$parked/${run#results/}
    mkdir -p "$(dirname "$dest")"
    if ! [ -f "$run/config.toml" ] || ! [ -f "$run/metrics.csv" ]; then
        echo "skipping $run: no config.toml and metrics.csv, not a run directory" >&2
        return
    fi
    rm -rf "$dest.tmp"
    mkdir -p "$dest.tmp"
    cp "$run/config.toml" "$run/metrics.csv" "$dest.tmp/"
    for file in summary.json policy.ckpt; do
        if [ -f "$run/$file" ]; then cp "$run/$file" "$dest.tmp/"; fi
    done
    if [ -f "$run/logs/train.log" ]; then
        gzip -9 -n -c "$run/logs/train.log" > "$dest.tmp/train.log.gz"
    fi
    if completed "$run"; then
        echo "parked $run: completed" >&2
    elif [ "$with_checkpoints" = 0 ]; then
        # A checkpoint parked before stays: older than the run, it still saves its steps.
        if [ -f "$dest/checkpoint.tar.zst" ]; then
            mv "$dest/checkpoint.tar.zst" "$dest.tmp/"
            echo "parked $run: its curve so far and the checkpoint parked before" >&2
        else
            echo "parked $run: its curve so far (--with-checkpoints to continue it, not restart it)" >&2
        fi
    else
        ckpt=$(newest_complete "$run")
        if [ -n "$ckpt" ] && [ "$((10#$(basename "$ckpt")))" -lt "$min_checkpoint_steps" ]; then
            # Too early to be worth the repository's growth: the run would redo these steps.
            echo "parked $run: its curve so far (checkpoint $(basename "$ckpt") is below" \
                "$min_checkpoint_steps env steps, not parked)" >&2
        elif [ -n "$ckpt" ] && [ "$(parked_step "$dest")" = "$(basename "$ckpt")" ]; then
            # Parked already (restored from it, or parked by another script's stop): kept as is.
            mv "$dest/checkpoint.tar.zst" "$dest.tmp/"
            echo "parked $run: checkpoint $(basename "$ckpt"), parked before" >&2
        elif [ -n "$ckpt" ]; then
            # The directory's name is its env steps; the tar keeps it so restoring recreates it.
            tar -C "$run/checkpoints" -cf - "$(basename "$ckpt")" |
                zstd -19 --long=27 -T1 -q -c > "$dest.tmp/checkpoint.tar.zst"
            echo "parked $run: checkpoint $(basename "$ckpt")" \
                "($(du -h "$dest.tmp/checkpoint.tar.zst" | cut -f1))" >&2
        else
            echo "parked $run: no complete checkpoint yet, it would start again" >&2
        fi
    fi
    rm -rf "$dest"
    mv "$dest.tmp" "$dest"
}

restore() {
    local src=$1 run file
    run=results/${src#"$parked"/}
    mkdir -p "$(dirname "$run")"
    if [ -e "$run" ]; then
        echo "keeping $run: it exists (a live run is at least as new as its parked copy)" >&2
        return
    fi
    rm -rf "$run.tmp"
    mkdir -p "$run.tmp/logs" "$run.tmp/checkpoints"
    cp "$src/config.toml" "$src/metrics.csv" "$run.tmp/"
    for file in summary.json policy.ckpt; do
        if [ -f "$src/$file" ]; then cp "$src/$file" "$run.tmp/"; fi
    done
    if [ -f "$src/train.log.gz" ]; then
        gzip -d -c "$src/train.log.gz" > "$run.tmp/logs/train.log"
    fi
    if [ -f "$src/checkpoint.tar.zst" ]; then
        zstd -d --long=27 -q -c "$src/checkpoint.tar.zst" | tar -C "$run.tmp/checkpoints" -xf -
    fi
    mv "$run.tmp" "$run"
    echo "restored $run" >&2
}

# results/runs/<run> and results/<variant>/runs/<run> (a benchmark's --out), as parked under
# results/parked/runs/ and results/parked/<variant>/runs/.
with_checkpoints=0
# A checkpoint younger than this many env steps is not parked: it saves less than an hour of a
# core, and a packed checkpoint adds 25-50 MB to the repository's history each time.
min_checkpoint_steps=5000
case "${1:-}" in
    "" | --restore) ;;
    --with-checkpoints) with_checkpoints=1 ;;
    *)
        echo "unknown argument $1: expected --with-checkpoints or --restore" >&2
        exit 2
        ;;
esac
# The learning scripts park when they stop, often together (one SIGTERM each): one park at a
# time, or two would write the same run's .tmp directory at once.
mkdir -p results/runs
exec 9> results/runs/.park.lock
flock 9
if [ "${1:-}" = "--restore" ]; then
    for src in "$parked"/runs/*/ "$parked"/*/runs/*/; do
        case "$src" in *.tmp/) continue ;; esac # a park that did not finish
        if [ -d "$src" ]; then restore "${src%/}"; fi
    done
else
    for run in results/runs/*/ results/*/runs/*/; do
        case "$run" in "$parked"/* | *.tmp/) continue ;; esac
        if [ -d "$run" ]; then park "${run%/}"; fi
    done
fi
