#!/usr/bin/env bash
# Cortex-M3 cost of whole print jobs: the firmware's QEMU build (lm3s6965evb, -icount shift=0)
# prints each model streamed by the real host code, and its COST/MEM lines are summarised per
# model: instructions per triangle sliced, per layer for toolpath + planning (mean, max), step
# interrupt instructions per step (mean) and the worst interrupt, and the worst layer's
# real-time factor at 72 MHz and 1.5 cycles per instruction, against the targets (>= 20x,
# <= 150 instructions per step, worst interrupt < 900 cycles for 40 kHz on X and Y).
#
#   scripts/m3_hil_cost.sh [--echo] [MODEL.stl...]
#
# Default: the four HIL sample models and a generated banded cylinder (cylinder:R:H:SIDES:BAND
# in mm, one that fits the 64 KB firmware). A job that fails is reported and the script exits 1
# after the table of the others.
#
# Needs qemu-system-arm (apt-get install qemu-system-arm). STRATA_FIRMWARE_ELF skips the
# firmware build and uses that image.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${STRATA_FIRMWARE_ELF:-}" ]; then
  scripts/build_firmware.sh qemu
fi
args=("$@")
if [ "${#args[@]}" -eq 0 ] || { [ "${#args[@]}" -eq 1 ] && [ "${args[0]}" = "--echo" ]; }; then
  args+=(embodier_asc.stl embodier_hotend_v2.stl embodier_LM8UU_8p2pi.stl xyz_20mm_cube.stl
    cylinder:4:3:16:0.2)
fi
exec cargo run --quiet --release -p strata-host --example m3_cost -- "${args[@]}"
