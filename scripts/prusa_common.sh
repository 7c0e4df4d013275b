# Sourced by the PrusaSlicer calibration scripts (overhang_prusa.sh, coverage_prusa.sh,
# print_path_table.sh): PrusaSlicer's settings closest to Strata's defaults and one way to
# slice with them. Not in CI.

# 0.2 mm layers, 0.45 mm lines, 2 perimeters, 20 % rectilinear, 4 top and bottom layers.
PRUSA_SETTINGS=(--layer-height 0.2 --first-layer-height 0.2 --extrusion-width 0.45
  --perimeters 2 --fill-density 20% --fill-pattern rectilinear --top-solid-layers 4
  --bottom-solid-layers 4)

# Whether prusa-slicer is installed.
have_prusa() { command -v prusa-slicer >/dev/null; }

# PrusaSlicer's version, as it names itself (empty if unknown).
prusa_version() { prusa-slicer --help 2>&1 | grep -m1 -o 'PrusaSlicer-[^ ]*' || true; }

# prusa_slice STL GCODE [EXTRA_ARGS...]: slices STL with PRUSA_SETTINGS and the extra
# arguments into GCODE (its log in GCODE.log), unless GCODE is already there. Fails, saying
# so, when prusa-slicer does.
prusa_slice() {
  local stl="$1" gcode="$2"
  shift 2
  [ -s "$gcode" ] && return 0
  if ! prusa-slicer --export-gcode "${PRUSA_SETTINGS[@]}" "$@" -o "$gcode" "$stl" \
    >"$gcode.log" 2>&1; then
    echo "$(basename "$stl" .stl): prusa-slicer failed (see $gcode.log)" >&2
    rm -f "$gcode"
    return 1
  fi
}
