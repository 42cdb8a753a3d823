#!/usr/bin/env bash
# Coverage-guided fuzzing of every decoder of bytes from outside the process (issue 24 item 5):
# the libFuzzer targets of fuzz/ (cargo-fuzz), each run for N executions.
#
#   bash tools/fuzz.sh                  # every target, 1,000,000 executions each
#   bash tools/fuzz.sh 200000           # every target, 200,000 executions each
#   bash tools/fuzz.sh 60s              # every target, 60 seconds each
#   bash tools/fuzz.sh 1000000 config envelope   # only these targets
#
# Installs what it needs if missing (the nightly toolchain, cargo-fuzz), builds the targets
# (release, debug assertions and overflow checks, AddressSanitizer), writes each target's seeds
# (valid encodings made by the project's own encoders, plus deploy/configs/*.toml for `config`),
# runs it, and prints per target: executions, seconds, executions per second, corpus size and
# crashes. Writes results/fuzz.json. Exits non-zero if any target crashed (a panic, a failed
# check, an abort, a timeout, an allocation over the limit), naming the target and the input
# that did it (under fuzz/artifacts/<target>/; replay it with `<binary> <file>`).
#
# Environment: FUZZ_JOBS (cargo build jobs, default 2), FUZZ_SKIP_BUILD=1 (reuse the binaries),
# FUZZ_RSS_MB (memory limit per target, also the largest single allocation; default 2048).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

LIMIT="${1:-1000000}"
shift || true
if [[ "$LIMIT" =~ ^[0-9]+s$ ]]; then
    RUN_FLAGS=(-runs=-1 "-max_total_time=${LIMIT%s}")
elif [[ "$LIMIT" =~ ^[0-9]+$ ]]; then
    RUN_FLAGS=("-runs=$LIMIT")
else
    echo "usage: bash tools/fuzz.sh [RUNS | SECONDSs] [TARGET...]" >&2
    exit 2
fi

# target | -max_len | function fuzzed
TARGETS=(
    "stats_record|128|mbpo_wire::Stats::decode (StatsRecord)"
    "control_msg|64|mbpo_wire::ControlMsg::control_command / is_for / ack"
    "transition_batch|4096|mbpo_wire::transitions::check_header + RowLayout::unpack_into / push_into"
    "weights_header|32768|mbpo_wire::weights::check_weights_header + policy copy / ModelWireLayout::load_into"
    "model_snapshot|32768|mbpo_wire::ModelWireLayout::load_into"
    "envelope|4096|mbpo_net::protocol::decode (Envelope)"
    "config|8192|mbpo_train::ExperimentConfig::resolve / load (+ validate, to_toml)"
    "env_json|512|mbpo_runtime::Dims::of_run (env.json)"
    "run_plan|1024|mbpo_runtime::ResolvedRun::parse (run-plan.json, sent to every worker)"
    "checkpoint|16384|mbpo_train::checkpoint::read / verify (every role's file)"
    "checkpoint_manifest|2048|mbpo_train::checkpoint::latest (COMPLETE)"
)
if (($# > 0)); then
    wanted=" $* "
    selected=()
    for t in "${TARGETS[@]}"; do
        [[ "$wanted" == *" ${t%%|*} "* ]] && selected+=("$t")
    done
    if ((${#selected[@]} != $#)); then
        echo "unknown target among: $* (known: $(printf '%s ' "${TARGETS[@]%%|*}"))" >&2
        exit 2
    fi
    TARGETS=("${selected[@]}")
fi

# --- tools -------------------------------------------------------------------------------
if ! rustup run nightly rustc --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal
fi
if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

# --- build -------------------------------------------------------------------------------
TRIPLE="$(rustc -vV | sed -n 's/^host: //p')"
BIN_DIR="$ROOT/fuzz/target/$TRIPLE/release"
build_seconds=0
if [[ "${FUZZ_SKIP_BUILD:-0}" != 1 ]]; then
    echo "== building the fuzz targets (cargo +nightly fuzz build) =="
    start=$(date +%s)
    CARGO_BUILD_JOBS="${FUZZ_JOBS:-2}" nice -n 10 cargo +nightly fuzz build --fuzz-dir fuzz
    build_seconds=$(($(date +%s) - start))
    echo "built in ${build_seconds} s"
fi

# --- run ---------------------------------------------------------------------------------
SCRATCH_BASE=/dev/shm
[[ -d "$SCRATCH_BASE" && -w "$SCRATCH_BASE" ]] || SCRATCH_BASE="${TMPDIR:-/tmp}"
SCRATCH="$(mktemp -d "$SCRATCH_BASE/mbpo-fuzz.XXXXXX")"
trap 'rm -rf "$SCRATCH"' EXIT
export MBPO_FUZZ_SCRATCH="$SCRATCH"
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_odr_violation=0}"
RSS_MB="${FUZZ_RSS_MB:-2048}"

mkdir -p results
rows=()
failed=()
printf '%-20s %12s %9s %10s %8s %8s\n' target executions seconds exec/s corpus crashes
for entry in "${TARGETS[@]}"; do
    IFS='|' read -r name max_len what <<<"$entry"
    bin="$BIN_DIR/$name"
    [[ -x "$bin" ]] || { echo "$bin is missing: build first" >&2; exit 1; }
    corpus="fuzz/corpus/$name"
    seeds="$SCRATCH/seeds/$name"
    artifacts="fuzz/artifacts/$name"
    log="$SCRATCH/$name.log"
    mkdir -p "$corpus" "$artifacts"
    MBPO_FUZZ_SEEDS="$seeds" "$bin" -runs=0 >"$SCRATCH/$name.seeds.log" 2>&1 ||
        { cat "$SCRATCH/$name.seeds.log" >&2; echo "$name: writing its seeds failed" >&2; exit 1; }
    if [[ "$name" == config ]]; then
        cp deploy/configs/*.toml "$seeds/"
    fi
    before="$(ls -1 "$artifacts" | sort)"
    start=$(date +%s.%N)
    set +e
    "$bin" "${RUN_FLAGS[@]}" "-max_len=$max_len" -timeout=10 "-rss_limit_mb=$RSS_MB" \
        "-malloc_limit_mb=$RSS_MB" -print_final_stats=1 -artifact_prefix="$artifacts/" \
        "$corpus" "$seeds" >"$log" 2>&1
    status=$?
    set -e
    seconds=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    execs=${execs:-0}
    rate=$(awk -v n="$execs" -v s="$seconds" 'BEGIN { printf "%d", n / (s + 1e-6) }')
    corpus_n=$(find "$corpus" -type f | wc -l)
    new_artifacts="$(comm -13 <(echo "$before") <(ls -1 "$artifacts" | sort) | sed '/^$/d')"
    crashes=$(echo -n "$new_artifacts" | grep -c . || true)
    if ((status != 0)) && ((crashes == 0)); then
        crashes=1 # died without an artifact (e.g. killed): still a failure
    fi
    printf '%-20s %12s %9.1f %10s %8s %8s\n' "$name" "$execs" "$seconds" "$rate" "$corpus_n" "$crashes"
    artifact_json="null"
    if ((crashes > 0)); then
        first="$(echo "$new_artifacts" | head -1)"
        artifact_json="\"$artifacts/$first\""
        failed+=("$name: ${first:+$artifacts/$first} (exit $status; log: fuzz/artifacts/$name.log)")
        cp "$log" "fuzz/artifacts/$name.log"
        echo "---- $name: the end of its log ----" >&2
        tail -40 "$log" >&2
    fi
    rows+=("$(printf '{"target": "%s", "function": "%s", "executions": %s, "seconds": %.1f, "exec_per_s": %s, "corpus": %s, "crashes": %s, "max_len": %s, "crash_input": %s}' \
        "$name" "$what" "$execs" "$seconds" "$rate" "$corpus_n" "$crashes" "$max_len" "$artifact_json")")
done

{
    echo "{"
    echo "  \"date\": \"$(date -u +%Y-%m-%dT%H:%M:%SZ)\","
    echo "  \"commit\": \"$(git rev-parse --short HEAD 2>/dev/null || echo unknown)\","
    echo "  \"limit\": \"$LIMIT\","
    echo "  \"build_seconds\": $build_seconds,"
    echo "  \"targets\": ["
    for i in "${!rows[@]}"; do
        sep=","; ((i == ${#rows[@]} - 1)) && sep=""
        echo "    ${rows[$i]}$sep"
    done
    echo "  ]"
    echo "}"
} >results/fuzz.json
echo "wrote results/fuzz.json"

if ((${#failed[@]} > 0)); then
    echo "CRASHES:" >&2
    printf '  %s\n' "${failed[@]}" >&2
    exit 1
fi
echo "no crashes"
