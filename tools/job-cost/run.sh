#!/usr/bin/env bash
# Cortex-M3 cost of whole print jobs: the firmware's QEMU build (lm3s6965evb, -icount shift=0)
# prints each model streamed by the real host code, and its COST/MEM lines are summarised per
# model: instructions per triangle sliced, per layer for toolpath + planning (mean, max), step
# interrupt instructions per step (mean) and the worst interrupt, and the worst layer's
# real-time factor at 72 MHz and 1.5 cycles per instruction, against the targets (>= 20x,
# <= 150 instructions per step, worst interrupt < 900 cycles for 40 kHz on X and Y).
#
#   tools/job-cost/run.sh [--board qemu|qemu-mps2] [--echo] [MODEL.stl...]
#
# Default: embodier_asc, xyz_20mm_cube, embodier_hotend_v2, embodier_LM8UU_8p2pi (simplified
# by admission for the slicer, its offsets in bands) and a generated banded cylinder
# (cylinder:R:H:SIDES:BAND in mm) on the 64 KB build (`qemu`, lm3s6965evb), then LM8UU
# unsimplified, its offsets whole, on the same firmware built for mps2-an385 (`qemu-mps2`: the
# same Cortex-M3 instruction set with 4 MB of RAM). A job that fails is reported and the
# script exits 1 after the table of the others.
#
# Needs qemu-system-arm (apt-get install qemu-system-arm). STRATA_FIRMWARE_ELF skips the
# firmware build and uses that image.
set -euo pipefail
cd "$(dirname "$0")/../.."
board=qemu
if [ "${1:-}" = "--board" ]; then
  board="$2"
  shift 2
fi
run() { # board, job_cost arguments...
  local b="$1"
  shift
  if [ -z "${STRATA_FIRMWARE_ELF:-}" ]; then
    scripts/build_firmware.sh "$b" >&2
    STRATA_FIRMWARE_ELF="target/firmware/$b/strata-firmware.elf" \
      cargo run --quiet --release -p strata-host --example job_cost -- "$@"
  else
    cargo run --quiet --release -p strata-host --example job_cost -- "$@"
  fi
}
args=("$@")
if [ "${#args[@]}" -eq 0 ] || { [ "${#args[@]}" -eq 1 ] && [ "${args[0]}" = "--echo" ]; }; then
  status=0
  run qemu "${args[@]}" embodier_asc.stl xyz_20mm_cube.stl embodier_hotend_v2.stl \
    embodier_LM8UU_8p2pi.stl cylinder:4:3:16:0.2 || status=1
  run qemu-mps2 "${args[@]}" embodier_LM8UU_8p2pi.stl || status=1
  exit $status
fi
run "$board" "${args[@]}"
