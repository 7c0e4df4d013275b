#!/usr/bin/env bash
# The print-path table: retractions and travel (mm) of Strata's G-code against PrusaSlicer's
# of the same models at the same settings (0.2 mm layers, 0.45 mm lines, 2 perimeters, 20 %
# rectilinear, 4 top and bottom layers; PrusaSlicer's own retraction and travel defaults).
# Both G-codes are read the same way, their prints only (start and end code left out): a
# retraction is a move that pulls filament back without moving in XY, travel the XY length of
# the moves that do not extrude. Not in CI; PrusaSlicer's
# column is left out without prusa-slicer.
#
#   scripts/print_path_table.sh [OUT_DIR]   (default target/print_path; G-code there is reused)
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/prusa_common.sh
out="${1:-target/print_path}"
models=../shared/models
mkdir -p "$out"
cargo build --release -q -p strata-host --bin strata
strata=target/release/strata
bed=(--bed-shape 0x0,220x0,220x220,0x220 --center 110,110)
files=(xyz_20mm_cube.stl embodier_LM8UU_8p2pi.stl embodier_hotend_v2.stl
  prusashape_M3_hex_nut.stl 3DBenchy.stl scaled_mm/torus3_genus3_x30.stl
  scaled_mm/stanford_bunny_x60.stl)

# Retractions and travel mm of a G-code file's print (from its first `;LAYER_CHANGE` to its
# last `;TYPE:Custom`, the end sequence: start and end code left out; absolute or relative E,
# G92 resets).
path_figures() {
  awk '
    function num(w) { return substr(w, 2) + 0 }
    FNR == NR { if ($0 == ";TYPE:Custom") last = FNR; next }
    $0 == ";LAYER_CHANGE" { on = 1 }
    FNR >= last { on = 0 }
    /^M82/ { rel = 0 } /^M83/ { rel = 1 }
    /^G92/ { for (i = 2; i <= NF; i++) if ($i ~ /^E/) e = num($i) }
    /^G[01] / {
      nx = x; ny = y; de = 0; hase = 0
      for (i = 2; i <= NF; i++) {
        if ($i ~ /^;/) break
        if ($i ~ /^X/) nx = num($i)
        else if ($i ~ /^Y/) ny = num($i)
        else if ($i ~ /^E/) { v = num($i); de = rel ? v : v - e; e = rel ? e + v : v; hase = 1 }
      }
      moved = (nx != x || ny != y)
      if (on && hase && de < 0 && !moved) retractions++
      if (on && moved && !(hase && de > 0)) travel += sqrt((nx - x) ^ 2 + (ny - y) ^ 2)
      x = nx; y = ny
    }
    END { printf "%d %.0f\n", retractions, travel }' "$1" "$1"
}

echo "| model | Strata retractions | Strata travel mm | PrusaSlicer retractions | PrusaSlicer travel mm |"
echo "|---|---:|---:|---:|---:|"
for f in "${files[@]}"; do
  stl="$models/$f"
  [ -f "$stl" ] || continue
  name="$(basename "$f" .stl)"
  "$strata" slice "$stl" -o "$out/$name.strata.gcode" >/dev/null 2>&1 || {
    echo "| $name | refused | | | |"
    continue
  }
  read -r sr st < <(path_figures "$out/$name.strata.gcode")
  pr="" pt=""
  if have_prusa && prusa_slice "$stl" "$out/$name.prusa.gcode" "${bed[@]}"; then
    read -r pr pt < <(path_figures "$out/$name.prusa.gcode")
  fi
  echo "| $name | $sr | $st | $pr | $pt |"
done
