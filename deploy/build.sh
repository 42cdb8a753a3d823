#!/usr/bin/env bash
# Build the release binaries one role needs, side by side in target/release/ (the supervisor
# and `mbpo join` start the services from next to `mbpo`). The one list of which binaries
# each role runs:
#   bash deploy/build.sh cli        # `mbpo` alone: train, bench, plot, eval
#   bash deploy/build.sh pipeline   # `mbpo run` on one host: the supervisor and its services
#   bash deploy/build.sh head       # the pipeline and the gateway: `mbpo run --listen`, `mbpo certs`
#   bash deploy/build.sh worker     # a worker host, `mbpo join`: the CLI, the gateway, the actor
# With MuJoCo set up (`.mujoco/lib`, made by deploy/setup_mujoco.sh) it builds with
# `--features mujoco`. Every build then keeps the MuJoCo tasks once they are installed: the
# learning lanes start target/release/mbpo for each seed, and a build without the feature (for
# a benchmark, say) would replace their binary with one that has no MuJoCo tasks.
set -euo pipefail
cd "$(dirname "$0")/.."
pipeline=(-p mbpo -p mbpo-actor -p mbpo-model-trainer -p mbpo-rollout-generator -p mbpo-sac-learner)
case "${1-}" in
    cli) packages=(-p mbpo) ;;
    pipeline) packages=("${pipeline[@]}") ;;
    head) packages=("${pipeline[@]}" -p mbpo-gateway) ;;
    worker) packages=(-p mbpo -p mbpo-gateway -p mbpo-actor) ;;
    *)
        echo "deploy/build.sh: expected a role, cli, pipeline, head or worker; found '${1-}'" >&2
        exit 2
        ;;
esac
features=()
if [ -d .mujoco/lib ]; then
    features=(--features mujoco)
fi
cargo build --release --locked "${packages[@]}" "${features[@]}"
