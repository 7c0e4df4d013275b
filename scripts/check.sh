#!/usr/bin/env bash
# Every gate CI enforces, runnable the same way locally: formatting, lints, the no_std core and
# the firmware for the Cortex-M3, then all tests. Installs the Rust pieces it needs.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s ==\n' "$*"; }

step "toolchain pieces"
rustup target list --installed | grep -qx thumbv7m-none-eabi || rustup target add thumbv7m-none-eabi
rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt
rustup component list --installed | grep -q '^clippy' || rustup component add clippy
rustup component list --installed | grep -q '^llvm-tools' || rustup component add llvm-tools
# QEMU runs the firmware in the end-to-end test (which fails without it when CI is set).
if ! command -v qemu-system-arm >/dev/null && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  apt-get update && apt-get install -y qemu-system-arm
fi

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy (host crates, all targets) -D warnings"
cargo clippy --all-targets -- -D warnings

step "core for thumbv7m-none-eabi (no_std, no alloc)"
cargo build -p strata --target thumbv7m-none-eabi --release
step "firmware for thumbv7m-none-eabi (every board: build, clippy)"
for board in creality-v422 creality-v427 qemu-mps2 qemu; do
  scripts/build_firmware.sh "$board"
  cargo clippy -p strata-firmware --target thumbv7m-none-eabi --release --features "$board" -- -D warnings
done

step "step ISR: no division, no floating point (thumbv7m disassembly)"
scripts/check_isr_asm.sh

step "docs"
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps -p strata -p strata-host --quiet

step "tests"
log=$(mktemp)
cargo test --workspace --exclude strata-firmware 2>&1 | tee "$log"
# One closing line for the whole run (cargo prints one per test binary, doc tests last).
awk '/^test result:/ { p += $4; f += $6 } END { printf "\ntests: %d passed, %d failed\n", p, f }' "$log"
rm -f "$log"
