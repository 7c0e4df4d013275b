#!/usr/bin/env bash
# Where the firmware's instructions go on the emulated Cortex-M3: runs one print job as
# tools/job-cost/run.sh does (QEMU lm3s6965evb, the real host code streaming MODEL) with the
# symprof TCG plugin counting executed instructions per address, then attributes them to source
# functions through the ELF's debug info (innermost inlined frame; --depth N shows N frames;
# --own strata: library helpers inlined into the core count with their caller).
#
#   tools/job-profile/run.sh [--counted] MODEL.stl|cylinder:R:H:SIDES:BAND [--depth N] [--top K]
#     [--own PREFIX]
#
# --counted: only the instructions the real-time factor counts (the firmware's `service` calls
# that moved the pipeline and its `poll` calls that worked, in thread mode: the SysTick
# interrupts taken inside them left out), not the main loop's idle turns. Slower (a plugin
# callback per instruction).
#
# Needs gcc, qemu-system-arm and llvm-addr2line (rustup component llvm-tools, or apt llvm).
set -euo pipefail
cd "$(dirname "$0")/../.."
plugin_args=""
if [ "${1:-}" = "--counted" ]; then
  plugin_args=",on=strata_counted_on,off=strata_counted_off,keep=strata_counted_keep,isr=SysTick"
  shift
fi
model="$1"; shift
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
gcc -O2 -Wall -shared -fPIC -pthread -I../shared/tools/qemu-insncount \
  -o "$work/libsymprof.so" tools/job-profile/symprof.c
cat > "$work/qemu" <<EOS
#!/bin/sh
exec qemu-system-arm -plugin $work/libsymprof.so,out=$work/prof.txt$plugin_args "\$@"
EOS
chmod +x "$work/qemu"
if [ -z "${STRATA_FIRMWARE_ELF:-}" ]; then
  scripts/build_firmware.sh qemu >/dev/null
  export STRATA_FIRMWARE_ELF="$PWD/target/firmware/qemu/strata-firmware.elf"
fi
STRATA_QEMU="$work/qemu" cargo run --quiet --release -p strata-host --example job_cost -- "$model" | tail -1
sleep 1.5 # the plugin rewrites its table every second
# M3_PROFILE_OUT=FILE keeps the counts (attribute.py ELF FILE ... reads them again).
[ -z "${M3_PROFILE_OUT:-}" ] || cp "$work/prof.txt" "$M3_PROFILE_OUT"
python3 tools/job-profile/attribute.py "$STRATA_FIRMWARE_ELF" "$work/prof.txt" "$@"
