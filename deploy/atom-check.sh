#!/usr/bin/env bash
# Proves the Nao binaries run on the robots' CPUs, which no development machine has: builds the
# static Nao binary (deploy/build-nao.sh), runs it on the sample recording natively and under Debian's
# qemu-user with an Atom CPU model, and checks that
#   1. it runs there, and tract picked the kernels of a CPU without AVX (the log's `isa=`: the SSE
#      kernels of the patched tract-linalg on the V6, the generic ones on the V5),
#   2. its hypotheses equal the native run's,
#   3. AVX2 code dies there with SIGILL (a negative control: the emulated CPU really lacks AVX),
#   4. the daemon, started and asked to relocalise under strace, opens no NSS file (a static glibc
#      would load the robot's NSS libraries to resolve a host name).
#
#   deploy/atom-check.sh [v6] [v5]     (default: v6; CI runs v6)
#
# V6: Intel Atom E3845 (Silvermont: SSE4.2, no AVX/FMA/XSAVE) as a qemu CPU model: Nehalem with the
# Atom's family/model and the extensions it adds (movbe, aes, pclmulqdq, rdrand, erms).
# V5: 32-bit Atom N270-class, `qemu-i386 -cpu n270`.
set -euo pipefail
cd "$(dirname "$0")/.."

robots=("$@")
[ ${#robots[@]} -gt 0 ] || robots=(v6)

# What TRACT_CPU_ISA takes away to leave tract the kernels an Atom gets (SSE on x86_64, since
# vendor/tract-linalg; adding -sse4.1 would leave the generic ones).
GENERIC_ONLY=-avx,-avx2,-fma,-f16c,-avx512f,-avx512vnni,-avx512fp16,-avxvnni
ATOM_E3845='Nehalem,family=6,model=55,stepping=8,+movbe,+aes,+pclmulqdq,+rdrand,+erms,model-id=Intel(R) Atom(TM) CPU E3845 @ 1.91GHz'

if ! command -v qemu-x86_64 >/dev/null || ! command -v qemu-i386 >/dev/null || ! command -v strace >/dev/null; then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get install -y -q qemu-user strace >/dev/null 2>&1 \
        || { $sudo apt-get update -q >/dev/null && $sudo apt-get install -y -q qemu-user strace >/dev/null; }
fi

scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT

# Compares two replay outputs frame by frame, timings aside: exactly, or numbers within a tolerance.
compare() {
    python3 - "$@" <<'PY'
import json, sys
first, second, tolerance = sys.argv[1], sys.argv[2], float(sys.argv[3])
def frames(path):
    with open(path) as lines:
        return [{k: v for k, v in json.loads(line).items() if k != "timings"} for line in lines]
def numbers(value, path=""):
    if isinstance(value, dict):
        for key in sorted(value):
            yield from numbers(value[key], f"{path}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from numbers(item, f"{path}[{index}]")
    else:
        yield path, value
a, b = frames(first), frames(second)
if len(a) != len(b):
    sys.exit(f"{len(a)} frames against {len(b)}")
worst = 0.0
for index, (x, y) in enumerate(zip(a, b)):
    left, right = list(numbers(x)), list(numbers(y))
    if [k for k, _ in left] != [k for k, _ in right]:
        sys.exit(f"frame {index}: different keys")
    for (key, u), (_, v) in zip(left, right):
        if isinstance(u, (int, float)) and isinstance(v, (int, float)) and not isinstance(u, bool):
            worst = max(worst, abs(u - v))
            if abs(u - v) > tolerance:
                sys.exit(f"frame {index} {key}: {u} against {v}")
        elif u != v:
            sys.exit(f"frame {index} {key}: {u!r} against {v!r}")
print(f"{len(a)} frames, largest difference {worst:.3g}")
PY
}

fail() { echo "atom-check: FAIL: $*" >&2; exit 1; }

echo "== negative control: AVX2 code under the emulated Atom"
cat > "$scratch/avx2.c" <<'C'
/* One AVX2 instruction (vpaddd on 256-bit registers), as tract's AVX2 kernels use. */
int main(void) {
    __asm__ volatile("vpaddd %%ymm0, %%ymm0, %%ymm0" ::: "xmm0");
    return 0;
}
C
gcc -O1 -static -o "$scratch/avx2" "$scratch/avx2.c"
"$scratch/avx2" || fail "the AVX2 control program does not run natively: this check needs an AVX2 host"
set +e
qemu-x86_64 -cpu "$ATOM_E3845" "$scratch/avx2" >/dev/null 2>&1
status=$?
set -e
[ "$status" -eq 132 ] || fail "AVX2 code exited with $status under the Atom model, expected 132 (SIGILL)"
echo "AVX2 code dies with SIGILL (exit 132): the emulated CPU has no AVX2"

for robot in "${robots[@]}"; do
    case "$robot" in
        v6) emulate=(qemu-x86_64 -cpu "$ATOM_E3845") expected_isa="x86_64,sse4.1" ;;
        v5) emulate=(qemu-i386 -cpu n270) expected_isa="generic" ;;
        *) echo "usage: $0 [v6] [v5]" >&2; exit 2 ;;
    esac
    echo "== Nao $robot"
    binary="$(deploy/build-nao.sh "$robot")"
    RELOCD_LOG=info "$binary" replay > "$scratch/native.jsonl" 2> "$scratch/native.log" \
        || fail "$robot native run: $(cat "$scratch/native.log")"
    # The same kernels natively: what tract does on the robot, minus the emulation.
    TRACT_CPU_ISA="$GENERIC_ONLY" "$binary" replay > "$scratch/generic.jsonl" 2>/dev/null \
        || fail "$robot native run with the Atom's kernels"
    started=$(date +%s)
    RELOCD_LOG=info "${emulate[@]}" "$binary" replay > "$scratch/atom.jsonl" 2> "$scratch/atom.log" \
        || fail "$robot under ${emulate[*]:0:3}: exit $?: $(tail -5 "$scratch/atom.log")"
    echo "ran under ${emulate[0]} -cpu ${emulate[2]%%,*}… in $(( $(date +%s) - started )) s"

    isa="$(grep -o 'isa=[^ ]*' "$scratch/atom.log" | head -1)"
    [ "$isa" = "isa=$expected_isa" ] || fail "tract's kernels under the Atom model: '$isa', expected isa=$expected_isa"
    echo "tract kernels: $isa (no AVX; natively: $(grep -o 'isa=[^ ]*' "$scratch/native.log" | head -1))"

    lines=$(wc -l < "$scratch/atom.jsonl")
    [ "$lines" -eq 24 ] || fail "$robot relocalised $lines of the 24 sample frames"
    result="$(compare "$scratch/generic.jsonl" "$scratch/atom.jsonl" 0 2>&1)" \
        || fail "$robot: the Atom model's output differs from the native run with its kernels: $result"
    echo "equal to the native run with the same (Atom) kernels: $result"
    # The native run's own kernels (AVX/FMA on a desktop) sum in another order (and, with an int8
    # activation model, can move a rounding by a step): the same hypotheses, numbers a little apart
    # (seen with the int8 QDQ model: 2 mm in a sigma).
    result="$(compare "$scratch/native.jsonl" "$scratch/atom.jsonl" 0.05 2>&1)" \
        || fail "$robot: the Atom model's output differs from the native run's: $result"
    echo "equal to the native run with its own kernels within 0.05 (m, rad, probability): $result"

    # The daemon resolves no host names: static glibc would load the robot's NSS libraries for that.
    port=$((20000 + RANDOM % 20000))
    strace -f -qq -e trace=open,openat -o "$scratch/strace" "$binary" run --source sim --sensors off \
        --control "udp:127.0.0.1:$port" --publish "udp:127.0.0.1:$((port + 1))" 2> "$scratch/daemon.log" &
    daemon=$!
    python3 - "$port" <<'PY' || fail "the daemon under strace did not answer: $(tail -3 "$scratch/daemon.log")"
import sys, time
sys.path.insert(0, "examples")
from relocd_client import Control
control = Control(f"udp:127.0.0.1:{sys.argv[1]}", timeout=0.2)
for attempt in range(100):  # until the daemon is up
    try:
        print("the daemon answered a relocalisation request as trigger", control.relocalise())
        break
    except TimeoutError:
        pass
else:
    sys.exit(1)
time.sleep(1.0)  # the burst
PY
    pkill -TERM -P "$daemon"  # relocd, the child of strace
    wait "$daemon" || fail "the daemon did not stop cleanly on SIGTERM"
    if grep -E 'nsswitch|libnss|/etc/hosts|resolv\.conf' "$scratch/strace"; then
        fail "the daemon looked up host names (above): static glibc would load the robot's NSS libraries"
    fi
    echo "the daemon opened no NSS file (nsswitch.conf, hosts, resolv.conf, libnss_*)"
done
echo "atom-check: OK (${robots[*]})"
