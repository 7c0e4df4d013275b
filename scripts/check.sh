#!/usr/bin/env bash
# Every gate CI enforces, runnable the same way locally: formatting, lints, the no_std core and
# the firmware for the Cortex-M3, then all tests. Installs the Rust pieces it needs. Every
# gate and every test binary runs whatever failed before it; the last lines sum up the tests
# and name the failed gates, and the exit status is non-zero when anything failed.
set -uo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s ==\n' "$*"; }
failed=()
# Runs a gate; a failure is noted, not fatal.
gate() {
  local name=$1
  shift
  "$@" || failed+=("$name")
}

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
gate fmt cargo fmt --all -- --check

step "cargo clippy (host crates, all targets) -D warnings"
gate clippy cargo clippy --all-targets -- -D warnings

step "core for thumbv7m-none-eabi (no_std, no alloc)"
gate no_std cargo build -p strata --target thumbv7m-none-eabi --release
step "firmware for thumbv7m-none-eabi (every board: build, clippy)"
for board in creality-v422 creality-v427 qemu-mps2 qemu-rt qemu; do
  features="$board"
  [ "$board" = qemu-rt ] && features=qemu-realtime
  gate "firmware $board" scripts/build_firmware.sh "$board"
  gate "firmware clippy $board" cargo clippy -p strata-firmware --target thumbv7m-none-eabi \
    --release --features "$features" -- -D warnings
done

step "imports run one way (slice, step, toolpath)"
gate imports scripts/check_imports.sh

step "step ISR: no division, no floating point (thumbv7m disassembly)"
gate isr_asm scripts/check_isr_asm.sh

step "docs"
gate docs env RUSTDOCFLAGS="-D warnings" cargo doc --no-deps -p strata -p strata-host -p strata-testkit \
    --quiet

step "tests"
# Every test binary runs (no fail-fast); the closing line sums them all (a binary that
# crashed without a summary fails the run too).
log=$(mktemp)
status=0
cargo test --workspace --exclude strata-firmware --no-fail-fast 2>&1 | tee "$log" || status=$?
awk -v status="$status" '
  /^test result:/ { p += $4; f += $6 }
  END {
    printf "\ntests: %d passed, %d failed\n", p, f
    if (status != 0 && f == 0) printf "(a test binary failed without a test result: see above)\n"
  }' "$log"
rm -f "$log"
[ "$status" = 0 ] || failed+=(tests)

if [ ${#failed[@]} -gt 0 ]; then
  printf 'failed: %s\n' "$(IFS=,; echo "${failed[*]}")"
  exit 1
fi
echo "all gates passed"
