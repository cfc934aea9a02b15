#!/usr/bin/env bash
# A process of a running job is killed (SIGKILL, as when its node is lost);
# checks how the job ends:
#   lost_process.sh ROLE EXPECTED_EXIT MESSAGE_REGEX -- RUN.SH ARGS... --out DIR ...
# ROLE (display, traverse or datasend) is one the job cannot go on without.
# The job's run.sh arguments must hold --die-role ROLE (the test hook) and
# --out DIR. The job must end within 10 s of the kill with exit code
# EXPECTED_EXIT and a message matching MESSAGE_REGEX; the statistics written
# (at the end, or the last checkpoint when the display itself was lost) must
# be whole JSON, name the lost process when the display survived, and count
# no more frames than the PNG files written.
set -uo pipefail
role="$1" expected="$2" message="$3"
shift 3
[[ "$1" == "--" ]] && shift
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
source "$(dirname "${BASH_SOURCE[0]}")/job_out.sh"
job_out lost_process.sh "$@"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
timeout --kill-after=10 60 "$@" >"$log" 2>&1
code=$?
ended=$(date +%s.%N)
cat "$log"
echo "--- exit code $code"
fail() { echo "FAIL: $*"; exit 1; }
((code == 124 || code == 137)) && fail "the job did not end within 60 s (it hung)"
killed=$(grep -Eo 'killing this process at [0-9.]+' "$log" | grep -Eo '[0-9.]+$' | head -n1)
[[ -n "$killed" ]] || fail "the test hook never killed the $role process (the run ended first?)"
after=$(awk -v a="$killed" -v b="$ended" 'BEGIN{printf "%.1f", b - a}')
echo "the job ended ${after} s after the $role process was killed"
awk -v s="$after" 'BEGIN{exit !(s <= 10.0)}' || fail "the job took ${after} s to end after the loss (limit 10 s)"
((code == expected)) || fail "exit code $code, expected $expected"
grep -Eq -- "$message" "$log" || fail "output does not match /$message/"
[[ -f "$out/stats.json" ]] || fail "no statistics in $out/stats.json"
python3 - "$out" "$role" <<'PY' || fail "the statistics are not what was run"
import json, pathlib, sys
out, role = pathlib.Path(sys.argv[1]), sys.argv[2]
stats = json.loads((out / "stats.json").read_text())  # whole JSON, or this raises
frames = len(stats["frames"])
pngs = len(list(out.glob("frame_*.png")))
print(f"statistics: {frames} frames; {pngs} PNG frames written; lost: {stats.get('lost_processes')}")
assert frames <= pngs, "statistics count frames that were not written"
if role != "display":
    lost = stats["lost_processes"]
    assert len(lost) == 1 and lost[0]["role"] == role and not lost[0]["job_went_on"], lost
else:
    assert frames > 0, "no checkpoint of the statistics was written before the display was lost"
PY
echo "PASS"
