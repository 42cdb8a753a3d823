#!/usr/bin/env bash
# Runs the whole test suite: unit tests, gradient checks, Gymnasium replays, learning tests.
# Needs only the Rust toolchain (Gymnasium fixtures are committed; see tools/gym_reference.py).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --workspace --locked "$@"
