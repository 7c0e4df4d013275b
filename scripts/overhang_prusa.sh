#!/usr/bin/env bash
# Calibration of the extrusion-over-air checker (strata_testkit::overhang) against PrusaSlicer:
# the overhang parts, a 20 mm cube and 3DBenchy sliced by prusa-slicer with settings close to
# Strata's defaults (0.2 mm layers, 0.45 mm lines, 2 perimeters, 20 % rectilinear, 4 top and
# bottom layers), without and with supports, each G-code measured by the checker
# (examples/overhang_gcode.rs): one table per mode. Not in CI; does nothing without prusa-slicer.
#
#   scripts/overhang_prusa.sh [OUT_DIR]     (default target/overhang_prusa)
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/prusa_common.sh
if ! have_prusa; then
  echo "prusa-slicer not found (apt-get install prusa-slicer): nothing to calibrate against"
  exit 0
fi
out="${1:-target/overhang_prusa}"
cargo build --release -q --example overhang_gcode
check=target/release/examples/overhang_gcode
mkdir -p "$out/stl" "$out/plain" "$out/support"
"$check" stl "$out/stl" >/dev/null
benchy=../shared/models/3DBenchy.stl
[ -f "$benchy" ] && cp "$benchy" "$out/stl/3DBenchy.stl"
version="$(prusa_version)"
for mode in plain support; do
  extra=()
  [ "$mode" = support ] && extra=(--support-material)
  files=()
  for stl in "$out"/stl/*.stl; do
    name="$(basename "$stl" .stl)"
    gcode="$out/$mode/$name.gcode"
    # Sliced afresh each run (the parts may change).
    rm -f "$gcode"
    if prusa_slice "$stl" "$gcode" "${extra[@]}"; then
      files+=("$name=$gcode")
    fi
  done
  echo "## $version, $mode"
  echo
  "$check" check "${files[@]}"
done
