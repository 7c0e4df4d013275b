#!/usr/bin/env bash
# Calibration of the surface coverage checker (strata_testkit::coverage) against PrusaSlicer:
# the shared models that tests/toolpath_coverage.rs measures, sliced by prusa-slicer with
# Strata's default settings (0.2 mm layers, 0.45 mm lines, 2 perimeters, 20 % rectilinear,
# 4 top and bottom layers), each G-code measured against the model's own sections by
# examples/coverage_gcode.rs, at the checker's erosion and at the erosions given. Not in CI;
# does nothing without prusa-slicer.
#
#   scripts/coverage_prusa.sh [OUT_DIR] [EROSION_UM,...]   (default target/coverage_prusa)
# G-code already in OUT_DIR is reused: delete it to slice again.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/prusa_common.sh
if ! have_prusa; then
  echo "prusa-slicer not found (apt-get install prusa-slicer): nothing to calibrate against"
  exit 0
fi
out="${1:-target/coverage_prusa}"
erosion=()
[ -n "${2:-}" ] && erosion=(--erosion "$2")
models=../shared/models
cargo build --release -q --example coverage_gcode
check=target/release/examples/coverage_gcode
mkdir -p "$out"
version="$(prusa_version)"
# The model's bounding box centred at (200, 200) mm on a 400 mm bed: the checker's placement.
bed=(--bed-shape 0x0,400x0,400x400,0x400 --center 200,200)
# The models of tests/toolpath_coverage.rs (the same skips: the broken embodier_bin.stl, the
# originals about 1 mm in size, numpy-stl's parser cases of 2 to 4 mm).
files=(xyz_20mm_cube.stl embodier_asc.stl embodier_LM8UU_8p2pi.stl embodier_hotend_v2.stl
  prusashape_M3_hex_nut.stl prusashape_M3x10_screw.stl plate_holes.stl 3DBenchy.stl
  scaled_mm/fertility_genus4_x80.stl scaled_mm/rockerarm_genus1_x40.stl
  scaled_mm/stanford_bunny_x60.stl scaled_mm/torus3_genus3_x30.stl
  numpy-stl/stl_binary__rear_case.stl numpy-stl/stl_tests__bwb.stl)
args=()
for f in "${files[@]}"; do
  stl="$models/$f"
  [ -f "$stl" ] || { echo "$f: missing"; continue; }
  name="$(basename "$f" .stl)"
  gcode="$out/$name.gcode"
  if prusa_slice "$stl" "$gcode" "${bed[@]}"; then
    args+=("$name=$stl=$gcode")
  fi
done
echo "## $version"
echo
"$check" "${erosion[@]}" "${args[@]}"
