#!/usr/bin/env bash
# The behaviour oracle: per-layer step hashes (host and 64 KB board capacities), board step
# hashes, print ticks and G-code hashes of six models, one figure a line, to standard output.
# Save one run before a change that must not change behaviour and `diff` it with one after.
set -euo pipefail
cd "$(dirname "$0")/.."
m=../shared/models
cargo build --release -q -p strata-host --bin strata --example hash_oracle
target/release/examples/hash_oracle "$m/embodier_asc.stl" "$m/xyz_20mm_cube.stl" \
  "$m/embodier_hotend_v2.stl" "$m/embodier_LM8UU_8p2pi.stl" "$m/prusashape_M3_hex_nut.stl" \
  "$m/scaled_mm/torus3_genus3_x30.stl"
