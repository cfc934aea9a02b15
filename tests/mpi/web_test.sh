#!/usr/bin/env bash
# The browser viewer against a real running job:
#   web_test.sh BIN_DIR DATASET SCENARIO
# SCENARIO:
#   browser  pointillist-web relays for Debian's headless chromium, driven over
#            the DevTools protocol by web_browser.py (load, frame, screenshot,
#            drag, newer frame, screenshot; malformed, oversized and vanishing
#            WebSocket clients beside it); chromium missing is a failure, not a
#            skip: CI installs it (deploy/common.sh)
#   curve    the service on CURVE: pointillist-web with an authorized key relays
#            frames; one without keys tells its browser why it gets none
set -uo pipefail
BIN="$1" DATASET="$2" scenario="$3"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
source "$ROOT/tests/mpi/service_job.sh"
python=/usr/bin/python3
browser_test=("$python" "$ROOT/tests/mpi/web_browser.py")

# Starts pointillist-web on a free port; sets URL (and WEB_PID, WEB_LOG).
start_web() {
  WEB_LOG="$WORK/web-$RANDOM.log"
  "$BIN/pointillist-web" --connect "$ENDPOINT" --http 127.0.0.1:0 "$@" >"$WEB_LOG" 2>&1 &
  WEB_PID=$!
  URL=""
  for _ in $(seq 1 100); do
    URL=$(grep -Eo 'http://127\.0\.0\.1:[0-9]+/' "$WEB_LOG" | head -n1)
    [[ -n "$URL" ]] && break
    kill -0 "$WEB_PID" 2>/dev/null || fail "pointillist-web ended: $(cat "$WEB_LOG")"
    sleep 0.1
  done
  [[ -n "$URL" ]] || fail "pointillist-web did not say where it serves"
  echo "viewer at $URL"
}

# SIGTERM: a clean stop, exit code 0.
stop_web() {
  kill -TERM "$WEB_PID"
  local code=0
  wait "$WEB_PID" || code=$?
  echo "--- pointillist-web log"
  cat "$WEB_LOG"
  ((code == 0)) || fail "pointillist-web exited with $code after SIGTERM"
  grep -q "pointillist-web: stopped (SIGTERM)" "$WEB_LOG" || fail "no stop line from pointillist-web"
}

case "$scenario" in
  browser)
    command -v chromium >/dev/null || fail "chromium is not installed (deploy/common.sh installs it)"
    "$python" -c "import websocket, numpy" 2>/dev/null ||
      fail "python3-websocket or python3-numpy is not installed"
    start_service_job
    start_web
    # The page itself, and a 404 for anything else.
    "$python" - "$URL" <<'PY' || fail "HTTP checks"
import sys, urllib.request, urllib.error
page = urllib.request.urlopen(sys.argv[1]).read().decode()
assert "<canvas" in page and "pointillist" in page, "the page is not the viewer"
try:
    urllib.request.urlopen(sys.argv[1] + "etc/passwd")
    raise SystemExit("a path other than / was served")
except urllib.error.HTTPError as error:
    assert error.code == 404, error.code
print("HTTP: page served, other paths 404")
PY
    "${browser_test[@]}" "$URL" "$WORK" ${WEB_TEST_SAVE:+--save "$WEB_TEST_SAVE"} ||
      { cat "$WEB_LOG"; fail "browser checks"; }
    stop_web
    client=("$BIN/pointillist-client" --connect "$ENDPOINT" --timeout 30)
    ;;
  curve)
    for who in server web; do
      "$BIN/pointillist-client" keygen "$WORK/$who" >/dev/null || fail "keygen $who"
    done
    { echo "# pointillist-web"; cat "$WORK/web.public"; } >"$WORK/authorized"
    start_service_job --curve-secret-key "$WORK/server.secret" \
      --curve-authorized-keys "$WORK/authorized"
    keys=(--curve-server-key "$WORK/server.public" --curve-key "$WORK/web.secret")
    start_web "${keys[@]}"
    "${browser_test[@]}" "$URL" "$WORK" --raw frame || { cat "$WEB_LOG"; fail "no frame over CURVE"; }
    stop_web
    start_web --timeout 2
    "${browser_test[@]}" "$URL" "$WORK" --raw refused || { cat "$WEB_LOG"; fail "no refusal"; }
    stop_web
    client=("$BIN/pointillist-client" --connect "$ENDPOINT" --timeout 30 "${keys[@]}")
    ;;
  *)
    echo "unknown scenario $scenario" >&2
    exit 2
    ;;
esac

"${client[@]}" shutdown --reason "web test done" || fail "shutdown request"
wait_job_exit 60
((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
grep -q "shutdown complete" "$JOB_LOG" || fail "no clean shutdown"
assert_nothing_left
echo PASS
