# Sourced (from the repository root) by the scripts that build `target/release/mbpo`. Sets
# `pipeline_packages` (below) and `features`: `--features mujoco` when MuJoCo is set up
# (`.mujoco/lib`, made by deploy/setup_mujoco.sh), else nothing. Every build then keeps the
# MuJoCo tasks once they are installed: the learning lanes start `target/release/mbpo` for each
# seed, and a build without the feature (for a benchmark, say) would replace their binary with
# one that has no MuJoCo tasks.
features=()
# The packages of `mbpo run`'s pipeline on one host: the supervisor and the services it starts.
pipeline_packages=(-p mbpo -p mbpo-actor -p mbpo-model-trainer -p mbpo-rollout-generator -p mbpo-sac-learner)
if [ -d .mujoco/lib ]; then
    features=(--features mujoco)
fi
