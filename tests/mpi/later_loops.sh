#!/usr/bin/env bash
# A camera path played twice (--loops 2): the second loop shows the first
# loop's frames again, pixel for pixel, and moves at most 2 % of the first
# frame's bytes a frame (every view's data was sent during the first), fewer
# than the first loop's frames did on average. (Not fewer than its steady
# frames from frame 3: those already move under 1 % of the first frame, and
# on a loaded machine the cost scheduler's moves of work between renders
# took the second loop past them, 0.068 against 0.041 MiB a frame in 1 run
# of 16 beside a busy core.)
#   later_loops.sh RUN.SH ARGS... --loops 2 --out DIR ...
# The summary's "later loops" line and stats.json's *_later_loops figures are
# what the check reads.
set -uo pipefail
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
source "$(dirname "${BASH_SOURCE[0]}")/job_out.sh"
job_out later_loops.sh "$@"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
timeout --kill-after=10 120 "$@" >"$log" 2>&1
code=$?
cat "$log"
((code == 0)) || { echo "FAIL: the job exited with code $code"; exit 1; }
grep -q "^later loops (from frame " "$log" || { echo "FAIL: no 'later loops' line in the summary"; exit 1; }
python3 - "$out" <<'PY'
import hashlib, json, pathlib, sys
out = pathlib.Path(sys.argv[1])
stats = json.loads((out / "stats.json").read_text())
k = stats["key_figures"]
frames = k["frames"]
loop = k["later_loops_from"]
fail = []
if loop == 0 or frames != 2 * loop:
    sys.exit(f"FAIL: later loops from frame {loop} of {frames}: expected half of them")
# The same cameras: the same images.
pngs = sorted(out.glob("frame_*.png"))
if len(pngs) != frames:
    sys.exit(f"FAIL: {len(pngs)} frames written, expected {frames}")
digest = [hashlib.sha256(p.read_bytes()).hexdigest() for p in pngs]
differ = [i for i in range(loop) if digest[i] != digest[i + loop]]
if differ:
    fail.append(f"frames {differ[:5]} differ from the same frames of the second loop")
first = k["bytes_first_frame"]
later = k["bytes_per_frame_later_loops"]
first_loop_frames = [f["bytes_sent"] for f in stats["frames"] if f["frame"] < loop]
first_loop = sum(first_loop_frames) / len(first_loop_frames)
print(f"first frame {first / 2**20:.2f} MiB; first loop {first_loop / 2**20:.3f} MiB a frame; "
      f"later loops {later / 2**20:.3f} MiB a frame ({100 * later / first:.2f} %)")
if not first > 0:
    fail.append("the first frame moved no bytes")
if later > 0.02 * first:
    fail.append(f"the second loop moved {later:.0f} bytes a frame, over 2 % of the first frame's {first}")
if not later < first_loop:
    fail.append(f"the second loop moved no fewer bytes a frame ({later:.0f}) than the first ({first_loop:.0f})")
if fail:
    sys.exit("FAIL: " + "; ".join(fail))
print("PASS")
PY
