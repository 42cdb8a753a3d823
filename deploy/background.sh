#!/usr/bin/env bash
# Shared by the long background benchmarks (deploy/learning_mujoco.sh, deploy/learning_dmc.sh):
# sourced, not run.

# Yield the cores to anything else (builds, tests, speed figures). `nice` alone does not: with
# the kernel's autogroup scheduling (sched_autogroup_enabled = 1, as on these VMs) the CPU is
# shared between sessions first, and `setsid`, as the scripts' headers start them, makes a run a
# session of its own, so niced lanes still took half the CPU from a build started elsewhere
# (results/measurements.md, "A new machine (AMD EPYC with AVX-512)", 2026-11-29, commit
# dfb7710). An autogroup's weight is the nice value written to it; it is written only when the
# calling script leads its session (started by `setsid`), so that a run from a terminal never
# lowers the terminal's own session.
yield_cpu_to_other_work() {
    renice -n 19 -p $$ >/dev/null 2>&1 || true
    if [ "$(ps -o sid= -p $$ | tr -d ' ')" = "$$" ] && [ -w /proc/self/autogroup ]; then
        echo 19 > /proc/self/autogroup 2>/dev/null || true
    fi
}

# Wait for the child $1 and return its status. A trapped stop signal makes `wait` return early
# while the child (which got the signal too, and checkpoints) still runs: wait again then.
wait_for() {
    local status=0
    while true; do
        wait "$1" && return 0 || status=$?
        kill -0 "$1" 2>/dev/null || return "$status"
    done
}
