#!/usr/bin/env bash
# Keep long benchmark runs across fresh checkouts (issue 23's learning lanes run for days).
#
# results/runs/ is not in git: a run directory holds checkpoints of tens of MB, rewritten every
# 1000 env steps. A new checkout of the repository therefore starts without it, and every seed under
# way would start again from step 0 (session 19 lost 5 seeds, about 30 core-hours, that way). So:
#
#   bash deploy/park_runs.sh            pack results/runs/<run>/ into results/parked/<run>/
#   bash deploy/park_runs.sh --restore  unpack every parked run that results/runs/ does not hold
#
# A parked run is what `mbpo bench learning` and `mbpo plot` need to go on: config.toml,
# metrics.csv, summary.json and policy.ckpt (once completed) and logs/train.log (gzip; `bench breakdown` reads its
# trainings from it) -- and, for a run not yet completed, its newest complete checkpoint as
# checkpoint.tar.zst (zstd -19: a Hopper checkpoint at 5000 steps packs from 16 MB into 4.6 MB), so
# the same benchmark command continues it exactly where it was. The TensorBoard file and the
# older checkpoints (the `checkpoint.keep_every` ones `bench breakdown`/`diagnose` start from)
# stay behind: they would make the repository grow by far more than the curves are worth.
#
# Restoring never touches a run directory that exists: the live one is always at least as new.
# Commit results/parked/ after parking; `deploy/learning_mujoco.sh` parks when it stops and
# restores when it starts.
set -euo pipefail
cd "$(dirname "$0")/.."
runs=results/runs
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

completed() {
    [ -f "$1/summary.json" ] && grep -q '"status": *"completed"' "$1/summary.json"
}

park() {
    local run=$1 name dest ckpt file
    name=$(basename "$run")
    dest=$parked/$name
    if ! [ -f "$run/config.toml" ] || ! [ -f "$run/metrics.csv" ]; then
        echo "skipping $run: no config.toml and metrics.csv, not a run directory" >&2
        return
    fi
    mkdir -p "$dest.tmp"
    cp "$run/config.toml" "$run/metrics.csv" "$dest.tmp/"
    for file in summary.json policy.ckpt; do
        if [ -f "$run/$file" ]; then cp "$run/$file" "$dest.tmp/"; fi
    done
    if [ -f "$run/logs/train.log" ]; then
        gzip -9 -n -c "$run/logs/train.log" > "$dest.tmp/train.log.gz"
    fi
    if completed "$run"; then
        echo "parked $name: completed" >&2
    else
        ckpt=$(newest_complete "$run")
        if [ -n "$ckpt" ]; then
            # The directory's name is its env steps; the tar keeps it so restoring recreates it.
            tar -C "$run/checkpoints" -cf - "$(basename "$ckpt")" |
                zstd -19 -T1 -q -c > "$dest.tmp/checkpoint.tar.zst"
            echo "parked $name: checkpoint $(basename "$ckpt")" \
                "($(du -h "$dest.tmp/checkpoint.tar.zst" | cut -f1))" >&2
        else
            echo "parked $name: no complete checkpoint yet, it would start again" >&2
        fi
    fi
    rm -rf "$dest"
    mv "$dest.tmp" "$dest"
}

restore() {
    local src=$1 name run file
    name=$(basename "$src")
    run=$runs/$name
    if [ -e "$run" ]; then
        echo "keeping $run: it exists (a live run is at least as new as its parked copy)" >&2
        return
    fi
    mkdir -p "$run.tmp/logs" "$run.tmp/checkpoints"
    cp "$src/config.toml" "$src/metrics.csv" "$run.tmp/"
    for file in summary.json policy.ckpt; do
        if [ -f "$src/$file" ]; then cp "$src/$file" "$run.tmp/"; fi
    done
    if [ -f "$src/train.log.gz" ]; then
        gzip -d -c "$src/train.log.gz" > "$run.tmp/logs/train.log"
    fi
    if [ -f "$src/checkpoint.tar.zst" ]; then
        zstd -d -q -c "$src/checkpoint.tar.zst" | tar -C "$run.tmp/checkpoints" -xf -
    fi
    mv "$run.tmp" "$run"
    echo "restored $run" >&2
}

if [ "${1:-}" = "--restore" ]; then
    mkdir -p "$runs"
    for src in "$parked"/*/; do
        if [ -d "$src" ]; then restore "${src%/}"; fi
    done
else
    mkdir -p "$parked"
    for run in "$runs"/*/; do
        if [ -d "$run" ]; then park "${run%/}"; fi
    done
fi
