#!/usr/bin/env bash
# What the 64 KB board takes of the sample models: every STL in ../shared/models and
# ../shared/models/scaled_mm through `strata simulate --max-deviation MM` (admission against the
# 64 KB build's capacities, then the whole job in simulation), one table row each: admitted or
# not, triangles streamed, measured deviation, the peak per-layer needs (active triangles,
# contour points, offset edges, loops, scanline crossings, path points), underruns, stops
# waiting for the link and print time; a refused model gets the refusal's first words.
#
#   scripts/capacity_table.sh [MM]        (default 0.05; STRATA_TABLE_TIMEOUT=S per model, 600)
set -euo pipefail
cd "$(dirname "$0")/.."
mm="${1:-0.05}"
limit="${STRATA_TABLE_TIMEOUT:-600}"
cargo build --release -q -p strata-host
models_dir="${STRATA_MODELS:-../shared/models}"
printf '%-32s %-9s %8s %7s %7s %7s %6s %5s %6s %6s %4s %4s %9s\n' model result tris dev_mm \
  active points edges loops cross path und wait print_s
for f in "$models_dir"/*.stl "$models_dir"/scaled_mm/*.stl; do
  name="$(basename "$f" .stl)"
  [ "$(dirname "$f")" = "$models_dir/scaled_mm" ] && name="scaled_mm/$name"
  out="$(timeout "$limit" target/release/strata simulate "$f" --max-deviation "$mm" --json 2>&1)" \
    || true
  OUT="$out" python3 - "$name" <<'PY'
import json, os, sys
name, text = sys.argv[1], os.environ["OUT"]
try:
    d = json.loads(text)
except ValueError:
    msg = " ".join(text.split()).split(": error: ", 1)[-1]
    if msg.startswith(("../", "/")):
        msg = msg.split(": ", 1)[-1]
    print(f"{name:<32} refused   {msg[:150] or '(no output: timed out?)'}")
    sys.exit(0)
n, s = d["device_needs"], d.get("simplified") or {}
res, dev = ("simplif.", s["max_deviation_mm"]) if s else ("whole", 0.0)
print(f"{name:<32} {res:<9} {d['triangles']:>8} {dev:>7.3f} {n['active_triangles']:>7} "
      f"{n['contour_points']:>7} {n['toolpath_points']:>6} {n['toolpath_loops']:>5} "
      f"{n['scan_crossings']:>6} {n['path_points']:>6} {d['underruns']:>4} "
      f"{d['rest_waits']:>4} {d['print_time_s']:>9.0f}")
PY
done
