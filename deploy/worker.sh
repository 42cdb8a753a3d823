#!/usr/bin/env bash
# Make this host a worker of a multi-host run: builds the release binaries if needed, then runs
# `mbpo join <head endpoint> [options]`, e.g.
#   deploy/worker.sh tls/10.0.0.1:7447 --credentials ~/mbpo-worker --actors-per-core 1
# The credentials are a copy of the head's `mbpo certs --out DIR` DIR/worker. A Python env
# (`env = "gym:..."`) also needs `bash deploy/setup_python.sh` here once, a MuJoCo task
# `bash deploy/setup_mujoco.sh` (before this script, whose build then has the feature). As a
# service that rejoins after every run: deploy/mbpo-worker@.service.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ]; then
    echo "usage: deploy/worker.sh <head endpoint, e.g. tls/10.0.0.1:7447> [mbpo join options]" >&2
    exit 2
fi
bash deploy/build.sh worker
exec target/release/mbpo join "$@"
