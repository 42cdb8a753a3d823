#!/usr/bin/env bash
# MBPO on AArch64, checked from an x86-64 machine: cross-builds for aarch64-unknown-linux-gnu and
# runs under QEMU's user mode (Debian's qemu-user; a slow emulation, so nothing here is a speed
# figure). Prints:
#   1. the short MBPO run of tests/tests/cross_cpu.rs natively and on AArch64: both policy
#      hashes and the metrics that differ (faer's GEMMs take other kernels off x86-64 with FMA:
#      mbpo_nn::simd::faer_x86_gemm_kernels);
#   2. MuJoCo: 300 random-action steps of Hopper-v5 with two evaluations every 100 (the env
#      alone: no SAC update yet) on both, with MuJoCo 3.17.0's AArch64 library from its PyPI
#      wheel, and the metrics that differ;
#   3. how many GEMM shapes give other bits (`mbpo-nn --example gemm_bits`, 8788 products);
#   4. the AArch64 unit tests of the numeric crates (gradient checks, ensembles, SAC, planners;
#      the no-allocation tests print SKIPPED there: mbpo_nn::gemm::allocation_free).
# Installs what it needs when root (gcc-aarch64-linux-gnu, qemu-user, the rustup target; MuJoCo
# through deploy/setup_mujoco.sh). Most of the time is the two builds: 13 min with them partly
# cached (results/measurements.md, "AArch64 under QEMU", 2026-11-29, commit 4cb2acf); from
# nothing, longer.
# Usage: bash tools/compare_aarch64.sh
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
[ "$(uname -m)" = x86_64 ] || { echo "compares x86-64 with AArch64: run it on an x86-64 machine" >&2; exit 1; }
target=aarch64-unknown-linux-gnu
if ! command -v aarch64-linux-gnu-gcc >/dev/null || ! command -v qemu-aarch64 >/dev/null; then
    [ "$(id -u)" = 0 ] || { echo "needs aarch64-linux-gnu-gcc and qemu-aarch64: run as root, or apt-get install gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user" >&2; exit 1; }
    apt-get install -y -qq gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user >/dev/null 2>&1 ||
        { apt-get update -qq && apt-get install -y -qq gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user >/dev/null; }
fi
rustup target list --installed | grep -qx "$target" || rustup target add "$target"
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L /usr/aarch64-linux-gnu"
qemu=(qemu-aarch64 -L /usr/aarch64-linux-gnu -E "LD_LIBRARY_PATH=$repo/target/$target-mujoco/lib")
bash deploy/setup_mujoco.sh >&2
# MuJoCo's AArch64 library, from the same release's wheel for that platform (PyPI).
arm_mujoco="$repo/target/$target-mujoco"
if [ ! -e "$arm_mujoco/lib/libmujoco.so" ]; then
    mkdir -p "$arm_mujoco/lib"
    .venv/bin/python -m pip download --quiet --disable-pip-version-check --no-deps \
        --only-binary=:all: --platform manylinux_2_28_aarch64 -d "$arm_mujoco" \
        "$(grep '^mujoco==' tools/requirements-mujoco.txt)"
    .venv/bin/python - "$arm_mujoco" <<'PY'
import glob, sys, zipfile
out = sys.argv[1]
wheel = zipfile.ZipFile(glob.glob(f"{out}/mujoco-*aarch64*.whl")[0])
lib = next(n for n in wheel.namelist() if n.startswith("mujoco/libmujoco.so."))
open(f"{out}/lib/{lib.split('/')[-1]}", "wb").write(wheel.read(lib))
PY
    # The linker takes libmujoco.so; the loader then looks for the SONAME, libmujoco.so.<version>.
    ln -sf "$(cd "$arm_mujoco/lib" && ls libmujoco.so.*)" "$arm_mujoco/lib/libmujoco.so"
fi
# Both builds name their target, so target/release (e.g. the lanes' build) is left as it is.
host=x86_64-unknown-linux-gnu
cargo build --release --locked --target "$host" -p mbpo --features mujoco 2>&1 | tail -1 >&2
MUJOCO_DYNAMIC_LINK_DIR="$arm_mujoco/lib" \
    cargo build --release --locked --target "$target" -p mbpo --features mujoco 2>&1 | tail -1 >&2
for t in "$host" "$target"; do
    cargo build --release --locked --target "$t" -p mbpo-nn --example gemm_bits 2>&1 | tail -1 >&2
done
here=target/$host/release
arm=target/$target/release
out="$(mktemp -d /tmp/compare-aarch64.XXXXXX)"
echo "runs in $out" >&2

# Runs `mbpo ARGS` natively and on AArch64 as run NAME; prints both policy hashes and, per
# evaluation, the metrics that differ.
compare_run() {
    local name=$1
    shift
    "$here/mbpo" "$@" --out "$out/$name-x86_64" >"$out/$name-x86_64.json" 2>"$out/$name-x86_64.log"
    "${qemu[@]}" "$arm/mbpo" "$@" --out "$out/$name-aarch64" >"$out/$name-aarch64.json" 2>"$out/$name-aarch64.log"
    echo "== $name"
    grep -h "CPU kernels" "$out/$name-x86_64.log" "$out/$name-aarch64.log" | sed 's/^.*CPU kernels/CPU kernels/' | cut -c1-160
    python3 - "$out" "$name" <<'PY'
import csv, json, sys
out, name = sys.argv[1:]
rows = {a: list(csv.DictReader(open(f"{out}/{name}-{a}/metrics.csv"))) for a in ("x86_64", "aarch64")}
for a in rows:
    print(f"{a}: policy_sha256 {json.load(open(f'{out}/{name}-{a}.json'))['policy_sha256']}")
timing = {"wall_seconds", "env_steps_per_sec", "updates_per_sec"}
for x, y in zip(rows["x86_64"], rows["aarch64"]):
    differ = [k for k in x if k not in timing and x[k] != y[k]]
    print(f"  at {x['env_steps']} env steps: " + (", ".join(f"{k} {x[k]} vs {y[k]}" for k in differ) or "every metric equal"))
PY
}

# 1. The run of tests/tests/cross_cpu.rs (pendulum-tiny, 104-wide layers, 2 threads).
compare_run pendulum train --config deploy/configs/pendulum-tiny.toml --steps 230 \
    --set "model.hidden=[104,104]" --set "sac.hidden=[104,104]" --set model.threads=2 \
    --set sac.threads=2 --set model.max_epochs=2 --set mbpo.updates_per_step=1 \
    --set eval.every=100 --set eval.episodes=1
# 2. MuJoCo alone: Hopper-v5's first 300 steps are random actions (the paper's warm-up is 5000).
compare_run hopper train --config deploy/configs/hopper.toml --steps 300 --set eval.every=100 \
    --set eval.episodes=2

# 3. GEMM shapes.
"$here/examples/gemm_bits" >"$out/gemm-x86_64.txt"
"${qemu[@]}" "$arm/examples/gemm_bits" >"$out/gemm-aarch64.txt"
echo "GEMM products with other bits on AArch64: $(diff "$out/gemm-x86_64.txt" "$out/gemm-aarch64.txt" | grep -c '^<' || true) of $(wc -l <"$out/gemm-x86_64.txt")"

# 4. Unit tests of the numeric crates on AArch64 (their slow learning tests left out).
cargo test --release --locked --target "$target" -p mbpo-nn -p mbpo-sac -p mbpo-model -p mbpo-plan \
    --lib --test gradcheck --test input_grad --test no_alloc --test rollout -- --nocapture 2>&1 |
    grep -E "^test result|FAILED|SKIPPED" || true
