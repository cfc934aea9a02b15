#!/usr/bin/env bash
# Runs a command (usually an MPI job) and checks how it ends:
#   expect_job.sh [--fail] [--within SECONDS] [--output REGEX]... [--max-cpu-idle X] -- COMMAND...
# --fail: the command must exit non-zero (and not by our time-out).
# --output: each regex must match the combined stdout+stderr.
# --max-cpu-idle: the display's "cpu since ready: X core-seconds" must be below X.
set -uo pipefail
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
want_fail=0
within=120
max_cpu=""
patterns=()
while (($#)); do
  case "$1" in
    --fail) want_fail=1; shift ;;
    --within) within="$2"; shift 2 ;;
    --output) patterns+=("$2"); shift 2 ;;
    --max-cpu-idle) max_cpu="$2"; shift 2 ;;
    --) shift; break ;;
    *) echo "expect_job.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
log=$(mktemp)
trap 'rm -f "$log"' EXIT
start=$(date +%s.%N)
timeout --kill-after=10 "$within" "$@" >"$log" 2>&1
code=$?
elapsed=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b-a}')
cat "$log"
echo "--- exit code $code after ${elapsed}s"
if ((code == 124 || code == 137)); then
  echo "FAIL: the job did not end within ${within}s (it hung)"
  exit 1
fi
if ((want_fail)) && ((code == 0)); then
  echo "FAIL: the job was expected to fail but exited 0"
  exit 1
fi
if ((!want_fail)) && ((code != 0)); then
  echo "FAIL: the job exited with code $code"
  exit 1
fi
for pattern in "${patterns[@]}"; do
  if ! grep -Eq -- "$pattern" "$log"; then
    echo "FAIL: output does not match /$pattern/"
    exit 1
  fi
done
if [[ -n "$max_cpu" ]]; then
  cpu=$(grep -Eo 'cpu since ready: [0-9.]+' "$log" | grep -Eo '[0-9.]+$' | tail -n1)
  if [[ -z "$cpu" ]]; then
    echo "FAIL: no 'cpu since ready' figure in the output"
    exit 1
  fi
  if ! awk -v c="$cpu" -v m="$max_cpu" 'BEGIN{exit !(c < m)}'; then
    echo "FAIL: idle ranks used $cpu core-seconds, limit $max_cpu"
    exit 1
  fi
  echo "idle CPU $cpu core-seconds < $max_cpu"
fi
echo PASS
