#!/usr/bin/env bash
# Counts instructions per relocalisation stage on the Atom's code path, deterministically, and turns
# them into an Atom E3845 latency estimate.
#
#   bench/atom-instructions.sh [BINARY] [MODEL ...]
#
# BINARY defaults to the static Nao V6 build (deploy/build-nao.sh v6); MODELS to the built-in one.
# Each stage runs under `valgrind --tool=callgrind` with TRACT_CPU_ISA taking away every AVX-era
# feature, so tract uses the generic kernels an Atom gets; the count of 1 run is subtracted from
# the count of 1 + N runs, which leaves N runs of the stage and nothing of start-up or model loading
# (N = 10; 1000 for the microsecond stages, whose counts are otherwise lost in start-up noise, 100 for
# the line points and one fit, 2 for a whole burst).
# Instruction counts are repeatable (same binary, input and environment), unlike times on a shared VM.
#
# The estimate assumes ATOM_IPC instructions per cycle (default 1.0) at 1.91 GHz (E3845 base clock):
# Silvermont is 2-wide out of order, so 1.0 is a middle guess for SSE float/int code; the real figure
# needs a robot. Override with ATOM_IPC=0.8 etc.
set -euo pipefail
cd "$(dirname "$0")/.."

binary="${1:-}"
[ -n "$binary" ] || binary="$(deploy/build-nao.sh v6)"
shift || true
models=("$@")
[ ${#models[@]} -gt 0 ] || models=("")
ipc="${ATOM_IPC:-1.0}"
command -v valgrind >/dev/null || { echo "valgrind is needed (Debian: apt-get install valgrind)" >&2; exit 1; }

export TRACT_CPU_ISA=-avx,-avx2,-fma,-f16c,-avx512f,-avx512vnni,-avx512fp16,-avxvnni

# Instructions executed by `relocd bench` timing STAGE ITERATIONS times.
count() {
    local model=$1 stage=$2 iterations=$3
    valgrind --tool=callgrind --callgrind-out-file=/dev/null "$binary" bench --stage "$stage" \
        --iterations "$iterations" ${model:+--model "$model"} 2>&1 >/dev/null \
        | sed -n 's/.*Collected : \([0-9]*\).*/\1/p'
}

printf '%-44s %-10s %16s %14s\n' model stage "instructions" "Atom est. ms"
for model in "${models[@]}"; do
    for stage in preprocess inference unfold fusion lines refine search total burst; do
        runs=10
        case "$stage" in unfold | fusion) runs=1000 ;; lines | refine) runs=100 ;; burst) runs=2 ;; esac
        one=$(count "$model" "$stage" 1)
        more=$(count "$model" "$stage" $((runs + 1)))
        per_run=$(( (more - one) / runs ))
        estimate=$(python3 -c "print(f'{$per_run / ($ipc * 1.91e9) * 1e3:.2f}')")
        printf '%-44s %-10s %16d %14s\n' "${model:-<built-in>}" "$stage" "$per_run" "$estimate"
    done
done
echo "(instructions per run of the stage on the generic kernels; estimate at IPC $ipc and 1.91 GHz)"
