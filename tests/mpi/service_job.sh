#!/usr/bin/env bash
# Starts a Pointillist job in serve mode for a test, on ipc endpoints in a
# fresh folder, and makes sure nothing of it outlives the test.
# Sourced by service_test.sh; expects BIN, DATASET and ROOT.
#   start_service_job [RUN.SH OPTIONS...]   sets WORK, ENDPOINT, JOB_PID, JOB_LOG
#   wait_job_exit SECONDS                  sets JOB_CODE; fails if the job is still up
#   assert_nothing_left                    no process names the test's folder
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
WORK=$(mktemp -d /tmp/pointillist-service.XXXXXX)
ENDPOINT="ipc://$WORK/control"
JOB_LOG="$WORK/job.log"
JOB_PID=""

cleanup() {
  if [[ -n "$JOB_PID" ]] && kill -0 "$JOB_PID" 2>/dev/null; then
    kill -KILL -- "-$JOB_PID" 2>/dev/null || true
  fi
  pkill -KILL -f -- "$WORK" 2>/dev/null || true
  rm -rf "$WORK"
}
trap cleanup EXIT

fail() {
  echo "FAIL: $*"
  [[ -f "$JOB_LOG" ]] && { echo "--- job log"; cat "$JOB_LOG"; }
  exit 1
}

start_service_job() {
  # Its own process group, so the cleanup can end every process of it.
  POINTILLIST_BUILD="$(dirname "$BIN")" setsid bash "$ROOT/deploy/run.sh" --layout 1,2,1,3 \
    --dataset "$DATASET" --serve --listen "$ENDPOINT" --size 480x270 "$@" >"$JOB_LOG" 2>&1 &
  JOB_PID=$!
  for _ in $(seq 1 600); do
    grep -q "service listening on" "$JOB_LOG" 2>/dev/null && return 0
    kill -0 "$JOB_PID" 2>/dev/null || fail "the job ended before it listened"
    sleep 0.2
  done
  fail "the job did not listen within 120 s"
}

wait_job_exit() {
  local seconds="$1"
  for _ in $(seq 1 $((seconds * 5))); do
    if ! kill -0 "$JOB_PID" 2>/dev/null; then
      wait "$JOB_PID"
      JOB_CODE=$?
      return 0
    fi
    sleep 0.2
  done
  fail "the job still runs ${seconds} s after it was told to stop"
}

assert_nothing_left() {
  sleep 0.5
  local left
  left=$(pgrep -af -- "$WORK" | grep -v pgrep || true)
  [[ -z "$left" ]] || fail "processes left behind: $left"
  echo "no process of the job is left"
}
