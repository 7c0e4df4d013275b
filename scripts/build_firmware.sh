#!/usr/bin/env bash
# Builds the firmware for one board and writes target/firmware/<board>/:
#   strata-firmware.elf   the image (QEMU: run it; Creality: debug symbols, RTT logs)
#   firmware.bin          the raw binary for the Creality SD bootloader (app at 0x0800_7000)
# and prints the section sizes (.data + .bss = static RAM; flash = .text + .rodata + .data).
#
#   scripts/build_firmware.sh creality-v422|creality-v427|qemu|qemu-mps2|qemu-rt
#
# qemu-rt is the 64 KB QEMU board with a real-time print clock (feature qemu-realtime: print
# ticks = instructions x STRATA_QEMU_CPI_X10 / 10, default 20): underruns counted, not
# prevented (`firmware/src/board/qemu.rs`).
# qemu-mps2 is QEMU's mps2-an385 (Cortex-M3, 4 MB of RAM) with capacities for the sample models
# unsimplified and their offsets whole: cost figures and HIL comparison only, not a board.
#
# Release build with LTO, one codegen unit and opt-level "s" (the root Cargo.toml's release
# profile, tightened through cargo's environment overrides so that only this build is
# affected). STRATA_FW_OPT_LEVEL overrides it: opt-level 2 makes slicing and planning about
# 7% cheaper but the step interrupt about 12 instructions a step dearer (the 64 KB build:
# 146 to 152 per step against the 150 budget, "s" 133 to 140), so "s" stays the default. Every
# image fits its flash at either level because the Printer static is all zero bytes (`.bss`,
# no flash image; checked below).
set -euo pipefail
cd "$(dirname "$0")/.."
# RAM the 64 KB boards leave free for what comes next (issue 21): statics + the deepest stack
# of the sample jobs + this <= 64 KB. The HIL test checks the same of every job it runs
# (`RAM_HEADROOM` in host/tests/hil_qemu.rs, against the stack's high-water mark).
RAM_HEADROOM=2048
# The deepest stack of the sample jobs on the 64 KB QEMU build (`MEM ... stack_hwm` after each
# job, the `stack` column of tools/job-cost/run.sh at 0.05 mm: 4,848 B for the whole
# scaled_mm/fertility_genus4_x80, 4,844 B for 3DBenchy, xyz_20mm_cube and the scaled rockerarm,
# bunny and torus), bytes, with 32 B to spare.
# The statics must leave it and RAM_HEADROOM free.
# The Creality builds run the same code under a main loop whose frame is 456 B smaller (552 B
# against 1,008: no instruction counter and its per-layer figures) and without the QEMU build's
# feed-interrupt figures (28 B), so they need 484 B less; 512 B less is reserved for them (the
# same 4,368 B as before the QEMU figures changed).
STACK_RESERVE_QEMU=4880
STACK_RESERVE_CREALITY=$((STACK_RESERVE_QEMU - 512))
board="${1:-}"
case "$board" in
  creality-v422|creality-v427|qemu|qemu-mps2|qemu-rt) ;;
  *) echo "usage: $0 creality-v422|creality-v427|qemu|qemu-mps2|qemu-rt" >&2; exit 2 ;;
esac
features="$board"
[ "$board" = qemu-rt ] && features=qemu-realtime
out="target/firmware/$board"
# A build that fails leaves no image: the HIL tests must not run one from an earlier build.
image=("$out/strata-firmware.elf" "$out/firmware.bin")
rm -f "${image[@]}"
fail() {
  echo "error: $board: $*" >&2
  rm -f "${image[@]}"
  exit 1
}
rustup target list --installed 2>/dev/null | grep -qx thumbv7m-none-eabi || rustup target add thumbv7m-none-eabi
rustup component list --installed 2>/dev/null | grep -q '^llvm-tools' || rustup component add llvm-tools
export CARGO_PROFILE_RELEASE_LTO=true
export CARGO_PROFILE_RELEASE_CODEGEN_UNITS=1
export CARGO_PROFILE_RELEASE_DEBUG=2
export CARGO_PROFILE_RELEASE_OPT_LEVEL="${STRATA_FW_OPT_LEVEL:-s}"
# defmt's RTT buffer (Creality boards): a few lines per job, 256 bytes leave RAM to the stack.
export DEFMT_RTT_BUFFER_SIZE="${DEFMT_RTT_BUFFER_SIZE:-256}"
cargo build -p strata-firmware --target thumbv7m-none-eabi --release --features "$features"
bin_dir="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"
objcopy="$(command -v rust-objcopy || echo "$bin_dir/llvm-objcopy")"
size="$(command -v rust-size || echo "$bin_dir/llvm-size")"
mkdir -p "$out"
cp target/thumbv7m-none-eabi/release/strata-firmware "$out/strata-firmware.elf"
# The PRINTER static must be zero-initialised (llvm-nm type b/B: .bss). A non-zero byte in
# `Printer::empty()` moves all of it (tens of KB) to .data, whose image takes flash.
nm="$(command -v rust-nm || echo "$bin_dir/llvm-nm")"
printer_type="$("$nm" "$out/strata-firmware.elf" | awk '$3 ~ /15strata_firmware7PRINTER/ { print $2 }')"
case "$printer_type" in
  b|B) ;;
  *) fail "the PRINTER static is not in .bss (llvm-nm type '${printer_type:-missing}'):" \
       "Printer::empty() has a non-zero byte; see src/slot.rs for the usual cause" ;;
esac
# No function's frame may take more than FRAME_LIMIT: a large value built on the stack (an
# enum's variant assigned through a temporary of its size, say) overflows it on the board only
# when that path runs. The deepest frames are about 900 B (the card's service).
FRAME_LIMIT=1536
objdump="$(command -v llvm-objdump || echo "$bin_dir/llvm-objdump")"
# Immediates in decimal (LLVM 14's objdump) or hex (`#0x1b4`, newer ones); a listing with no
# frame read at all fails too, so that another format cannot pass unchecked.
big_frame="$("$objdump" -d --no-show-raw-insn "$out/strata-firmware.elf" | awk -v limit=$FRAME_LIMIT '
  function value(s,   v, i) {
    if (s !~ /^0x/) return s + 0
    v = 0
    for (i = 3; i <= length(s); i++) v = v * 16 + index("0123456789abcdef", tolower(substr(s, i, 1))) - 1
    return v
  }
  /^[0-9a-f]+ <.*>:$/ { name = $2; frame = 0 }
  $2 ~ /^sub(\.w|w)?$/ && $3 == "sp," && $NF ~ /^#(0x[0-9a-fA-F]+|[0-9]+)$/ {
    frame += value(substr($NF, 2)); seen++
    if (frame > limit && !found) { found = name " " frame }
  }
  END { print (seen ? found : "none read (objdump format?)") }')"
[ -z "$big_frame" ] || fail "a stack frame over $FRAME_LIMIT B: $big_frame"
"$objcopy" -O binary "$out/strata-firmware.elf" "$out/firmware.bin"
read -r flash ram < <("$size" -A "$out/strata-firmware.elf" | awk '
  $1 == ".text" || $1 == ".rodata" || $1 == ".vector_table" { flash += $2 }
  $1 == ".data" { flash += $2; ram += $2 }
  $1 == ".bss" || $1 == ".uninit" { ram += $2 }
  END { print flash, ram }')
echo "$board: flash $flash bytes, static RAM (.data + .bss) $ram bytes"
# The stack takes the RAM the statics leave: at least STACK_RESERVE_* and RAM_HEADROOM on the
# 64 KB boards, so that a change that grows the statics into that room fails here, before any
# job runs.
case "$board" in
  qemu-mps2) ram_size=$((4 << 20)) stack=$STACK_RESERVE_QEMU headroom=0 ;;
  qemu|qemu-rt) ram_size=$((64 << 10)) stack=$STACK_RESERVE_QEMU headroom=$RAM_HEADROOM ;;
  *) ram_size=$((64 << 10)) stack=$STACK_RESERVE_CREALITY headroom=$RAM_HEADROOM ;;
esac
reserve=$((stack + headroom))
if [ $((ram_size - ram)) -lt "$reserve" ]; then
  fail "the statics leave $((ram_size - ram)) B of RAM, under the $reserve B the" \
    "deepest stack and the headroom need (STACK_RESERVE_*, RAM_HEADROOM in $0)"
fi
echo "$board: RAM left after the statics and the deepest stack: $((ram_size - ram - stack)) B"
echo "wrote $out/strata-firmware.elf and $out/firmware.bin ($(stat -c %s "$out/firmware.bin") bytes)"
