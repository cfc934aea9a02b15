#!/usr/bin/env bash
# A real job's traverse decisions, replayed through the simulator's traverse
# core: the same reports at the same times and the same tiles must give the
# same render choices, orders and packets (pointillist-simulate --replay).
#   replay_decisions_test.sh BIN_DIR DATASET [RUN.SH OPTIONS...]
set -euo pipefail
bin="$1" dataset="$2"
shift 2
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
POINTILLIST_BUILD="$(dirname "$bin")" timeout --kill-after=10 240 \
  bash "$root/deploy/run.sh" --dataset "$dataset" --quiet --decision-log "$work/decisions" "$@" \
  >"$work/job.log" 2>&1 || { cat "$work/job.log"; echo "FAIL: the job failed"; exit 1; }
logs=("$work"/decisions/*.decisions)
[[ -f "${logs[0]}" ]] || { echo "FAIL: no decision log was written"; exit 1; }
"$bin/pointillist-simulate" --dataset "$dataset" --replay "${logs[@]}"
