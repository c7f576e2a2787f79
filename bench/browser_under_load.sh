#!/usr/bin/env bash
# The browser tests N times in a row beside two busy loops (a busy CI machine), one line a run.
#
#   bench/browser_under_load.sh [N] [pytest options]     N defaults to 5
#
# Each run's output goes to test-artifacts/under-load-runK.log and its processes' logs
# stay in /tmp/under-load-runK/ (pytest's --basetemp), so a failure can be chased.
# Prints: run K rc=... (pytest's last line) wall=...s load before->after, at <commit>.
set -uo pipefail
case "${1:-}" in -h|--help) sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac
cd "$(dirname "$0")/.."
N=${1:-5}; shift || true
[ -x .venv/bin/python ] || { echo "no .venv: run ./dev test once first" >&2; exit 2; }
( while :; do :; done ) & B1=$!
( while :; do :; done ) & B2=$!
trap 'kill $B1 $B2 2>/dev/null' EXIT
mkdir -p test-artifacts
for i in $(seq 1 "$N"); do
  t0=$(date +%s); l0=$(cut -d' ' -f1 /proc/loadavg)
  rm -rf "/tmp/under-load-run$i"
  CI=true .venv/bin/python -m pytest -q -p no:cacheprovider --basetemp "/tmp/under-load-run$i" \
    -n 2 --dist loadgroup tests/browser "$@" > "test-artifacts/under-load-run$i.log" 2>&1
  rc=$?
  echo "run $i rc=$rc $(tail -1 "test-artifacts/under-load-run$i.log") wall=$(( $(date +%s) - t0 ))s" \
    "load ${l0}->$(cut -d' ' -f1 /proc/loadavg) at $(git rev-parse --short HEAD)"
done
