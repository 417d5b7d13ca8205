#!/usr/bin/env bash
# Builds relocd for a Nao with the host toolchain (no Docker): a stripped, statically linked binary.
#
#   deploy/build-nao.sh [v6|v5]      (default v6)
#
#   v6  x86_64-unknown-linux-gnu, -C target-cpu=silvermont (Atom E3845: SSE4.2, no AVX)
#   v5  i686-unknown-linux-gnu,   -C target-cpu=bonnell    (32-bit Atom; needs `rustup target add
#       i686-unknown-linux-gnu` and Debian's gcc-multilib)
#
# Both link glibc statically (+crt-static), so the robot's glibc version does not matter; relocd
# resolves no host names, so static glibc never loads the robot's NSS libraries. The binary has the
# V4L2 camera source (feature v4l: bindgen needs libclang-dev at build time) and no plotting.
# Prints the binary's path on stdout and its size on stderr. CARGO_TARGET_DIR is honoured.
set -euo pipefail
cd "$(dirname "$0")/.."

robot="${1:-v6}"
case "$robot" in
    v6) target=x86_64-unknown-linux-gnu cpu=silvermont ;;
    v5) target=i686-unknown-linux-gnu cpu=bonnell ;;
    *) echo "usage: $0 [v6|v5]" >&2; exit 2 ;;
esac

# Never target-cpu=native: the build machine has instructions the robot's Atom lacks. RUSTFLAGS from
# the environment are replaced, not extended, for the same reason.
export RUSTFLAGS="-C target-cpu=$cpu -C target-feature=+crt-static"
# --target is required: it keeps RUSTFLAGS away from build scripts and proc-macros, which run here.
# The `nao` profile (Cargo.toml): release with fat LTO in one codegen unit, for size.
cargo build --locked --profile nao --target "$target" --no-default-features --features v4l >&2

binary="${CARGO_TARGET_DIR:-target}/$target/nao/relocd"
strip "$binary"
if ! file_type="$(file -b "$binary" 2>/dev/null)"; then
    file_type="(file(1) not installed)"
fi
echo "relocd for the Nao $robot: $(du -h "$binary" | cut -f1) ($(stat -c %s "$binary") bytes), $file_type" >&2
echo "$binary"
