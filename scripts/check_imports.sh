#!/usr/bin/env bash
# The core's imports run one way (stages never name what sits above them): the slicer names
# neither the shared scratch nor the toolpath stage, the step stage not the simulation, the
# toolpath stage not the planner. Prints every offending line; fails on any.
set -uo pipefail
cd "$(dirname "$0")/.."
bad=0
rule() { # folder, forbidden path
  if grep -rn --include=*.rs "$2" "$1"; then
    echo "error: $1 names $2"
    bad=1
  fi
}
rule src/slice/ 'crate::scratch'
rule src/slice/ 'crate::toolpath'
rule src/step/ 'crate::sim'
rule src/toolpath/ 'crate::plan'
[ "$bad" = 0 ] && echo "OK: imports run one way"
exit "$bad"
