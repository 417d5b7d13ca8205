#!/usr/bin/env bash
# Fuzzes every input path of relocd for SECONDS each (default 60) and fails on the first crash.
#
#   fuzz/run.sh [SECONDS] [TARGET...]
#
# Needs a nightly toolchain (`rustup toolchain install nightly`) and cargo-fuzz (`cargo install
# cargo-fuzz`): libFuzzer with AddressSanitizer. The targets are fuzz/fuzz_targets/*.rs; each calls the
# check of the same name in src/fuzzing.rs. The checked-in seeds in fuzz/corpus/TARGET are read only:
# what the fuzzer finds goes to ~/.cache/relocd/fuzz/corpus/TARGET (override with RELOCD_FUZZ_DIR). A
# crash leaves its input in fuzz/artifacts/TARGET/: copy it into fuzz/corpus/TARGET/ under a name that
# says what it was, and `cargo test --test fuzz_corpus` keeps it as a regression test on stable Rust.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
shift || true
work="${RELOCD_FUZZ_DIR:-$HOME/.cache/relocd/fuzz}"
if [ $# -gt 0 ]; then targets=("$@"); else mapfile -t targets < <(cargo +nightly fuzz list); fi

printf '%-16s %14s %10s\n' target executions "exec/s"
for target in "${targets[@]}"; do
    mkdir -p "$work/corpus/$target"
    log="$work/$target.log"
    if ! cargo +nightly fuzz run --target-dir "$work/target" "$target" "$work/corpus/$target" \
        "fuzz/corpus/$target" -- -max_total_time="$seconds" -print_final_stats=1 > "$log" 2>&1; then
        tail -n 40 "$log" >&2
        echo "fuzz/run.sh: $target crashed (input in fuzz/artifacts/$target/)" >&2
        exit 1
    fi
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log")
    printf '%-16s %14s %10s\n' "$target" "$runs" "$rate"
done
echo "no crash in ${#targets[@]} targets, $seconds s each (logs in $work)"
