#!/usr/bin/env bash
# Executed-instruction counts of planner, step generator and step executor on an emulated
# Cortex-M3 (QEMU lm3s6965evb, 64 KB RAM, -icount shift=0), calibrated against a loop of
# known length. Needs qemu-system-arm (apt-get install qemu-system-arm).
#
# The step interrupt figures time every executor call on its own (SysTick at the core
# clock: 5 instructions per count) with pins that are one volatile store each (the real
# GPIO BSRR write): instructions per interrupt and per step (mean), the worst interrupt,
# and a run with X and Y both stepping at 40 kHz. Each run twice: "falls as events"
# (`Executor::on_timer`, every STEP fall an event) and as the firmware runs it
# (`on_timer_with` an emulated 72 MHz cycle counter at 1.5 cycles per instruction: pulses
# end in the call, any wait for the driver's high time counted; an emulated read costs
# about 5 instructions where the board's is one load). The generator is kept ahead of the
# executor (no run into an unrested horizon), as in a print. `M3_COST_OPT=s` builds with
# the firmware's opt-level ("s") instead of 3.
set -euo pipefail
cd "$(dirname "$0")/../.."
TARGET_DIR="${CARGO_TARGET_DIR:-$PWD/target}/stage_cost"
OPT="${M3_COST_OPT:-3}"
[ "$OPT" = 3 ] || TARGET_DIR="$TARGET_DIR-opt$OPT"
CARGO_PROFILE_RELEASE_OPT_LEVEL="$OPT" cargo build --quiet --manifest-path tools/stage-cost/Cargo.toml --release \
  --target thumbv7m-none-eabi --target-dir "$TARGET_DIR"
timeout 600 qemu-system-arm -cpu cortex-m3 -machine lm3s6965evb -nographic -icount shift=0 \
  -semihosting-config enable=on,target=native \
  -kernel "$TARGET_DIR/thumbv7m-none-eabi/release/stage_cost" 2>&1 | grep -v "period zero"
