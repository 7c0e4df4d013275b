#!/usr/bin/env bash
# The README's test command (scripts/check.sh) RUNS times in a row (default 3) while another
# process keeps every core busy (`stress-ng --cpu N` from apt, or N shell busy loops without
# it): the suite must decide the same on a saturated machine as on an idle one. Prints each
# run's closing lines and its duration; exits non-zero when a run failed.
set -uo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
cores=$(nproc)
pids=()
if command -v stress-ng >/dev/null; then
  stress-ng --cpu "$cores" --quiet &
  pids+=($!)
  load="stress-ng --cpu $cores"
else
  for _ in $(seq "$cores"); do
    (while :; do :; done) &
    pids+=($!)
  done
  load="$cores busy loops"
fi
trap 'kill "${pids[@]}" 2>/dev/null' EXIT
bad=0
for run in $(seq "$runs"); do
  log=$(mktemp)
  t0=$(date +%s)
  scripts/check.sh >"$log" 2>&1
  status=$?
  echo "run $run of $runs under $load: exit $status after $(( $(date +%s) - t0 )) s"
  grep -E '^tests: |^failed: |^all gates passed' "$log" | sed 's/^/  /'
  [ "$status" = 0 ] || { bad=1; cp "$log" "check_busy_run$run.log"; echo "  log: check_busy_run$run.log"; }
  rm -f "$log"
done
exit "$bad"
