#!/usr/bin/env bash
# The link of one simulated host (deploy/netns-cluster.sh: namespaces, veth,
# TCP) is cut for 3 s in the middle of a run, shorter than the peer timeout:
#   netns_link_cut_test.sh BIN_DIR DATASET
# Every frame must complete (1500, so the run goes on well after the link is
# back and the render processes behind it must draw again), none with a
# failed tile, the tiles held behind the cut must be re-issued
# (--tile-timeout 1) so that no frame waits more than two timeouts and a
# margin (2.5 s) for its predecessor, and no process may be taken for lost.
# The traverse says which render each tile went to, and the display names the
# renders holding an overdue tile in every task until they answer, so a
# re-issued tile mostly does not go behind the cut again (host 3 holds two of
# the four render processes): the wait is one timeout (1.01 s) in most runs.
# Two, not one: the first re-issue can still go to the other render behind
# the cut in the milliseconds before its own tile is overdue (CI saw 2.01 s
# once); that copy then waits a timeout of its own. Before the avoid lists,
# waits were 2.0-3.0 s and one tile failed after three attempts in CI.
# The hosts share this machine's cores, so auto would weigh render queues by
# 2/3 and work may stay off host 3 altogether; --render-core-share 1 spreads
# tiles as over separate machines. Even so the cost scheduler may keep every
# tile where the data already is (the city fits two render processes): in one
# CI run no tile went to host 3 and nothing was held behind the cut. The
# regions scheduler gives every render process a home region, so host 3 holds
# tiles when its link goes; re-issued tiles go where the cost function sends
# them among the renders not suspected.
# Exits 77 (ctest SKIP_RETURN_CODE) when this machine allows no namespaces.
set -uo pipefail
bin="$1" dataset="$2"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
# Host 3 holds two of the four render processes (three ranks per host).
POINTILLIST_BUILD="$(dirname "$bin")" timeout --kill-after=20 240 \
  bash "$root/deploy/netns-cluster.sh" --hosts 3 --layout 1,2,1,4 --cut-link 3:6:3 -- \
  --dataset "$dataset" --camera-path orbit --frames 1500 --size 480x270 --quiet \
  --tile-timeout 1 --render-core-share 1 --scheduler regions --out "$work/job" \
  >"$work/job.log" 2>&1
code=$?
cat "$work/job.log"
if ((code == 77)); then
  echo "SKIPPED: this machine does not allow network namespaces (see the message above)"
  exit 77
fi
((code == 0)) || { echo "FAIL: the job exited with code $code"; exit 1; }
# The cut and its end must fall inside the run (after ready, before shutdown).
order=$(grep -nE '^display: job .* ready|link of host 3 .*cut|link of host 3 restored|^display: shutdown complete' \
  "$work/job.log" | cut -d: -f2- | sed -E 's/^(display: job).*/ready/; s/.*cut for.*/cut/; s/.*restored/restored/; s/^display: shutdown.*/done/' | tr '\n' ' ')
[[ "$order" == "ready cut restored done " ]] || { echo "FAIL: the cut was not inside the run ($order)"; exit 1; }
python3 - "$work/job/stats.json" <<'PY'
import json, sys
stats = json.load(open(sys.argv[1]))
frames = stats["frames"]
failed = sum(f["failed_tiles"] for f in frames)
reissued = sum(f["reissued_tiles"] for f in frames)
avoiding = stats["key_figures"]["tasks_avoiding_silent_renders"]
gap = max(b["end"] - a["end"] for a, b in zip(frames, frames[1:]))
print(f"{len(frames)} frames, {reissued} tiles re-issued, {failed} failed, "
      f"{avoiding} handed out avoiding a silent render, "
      f"longest wait between frames {gap:.2f} s, lost: {stats['lost_processes']}")
assert len(frames) == 1500, "frames missing"
# The link is back 9 s after launch, before 9 s on the display's clock: the
# render processes behind it must draw again (their suspicion ends when they
# answer, or two timeouts on), not stay avoided for the rest of the run.
after = [f for f in frames if f["start"] > 10.5]
assert len(after) >= 50, f"the run ended too soon after the cut ({len(after)} frames after it)"
drawn = {rank: sum(f["splats_per_render"].get(rank, 0) for f in after) for rank in ("6", "7")}
print(f"after the cut: {len(after)} frames, render ranks 6 and 7 drew "
      f"{drawn['6']} and {drawn['7']} splats")
for rank, splats in drawn.items():
    assert splats > 0, f"render rank {rank} (behind the cut) drew nothing after the link was back"
assert failed == 0, "tiles failed"
assert reissued > 0, "no tile was held behind the cut (did it cut anything?)"
assert avoiding > 0, "tiles went out again with no render named to avoid"
assert gap < 2.5, "a frame waited longer than two tile timeouts and a margin"
assert not stats["lost_processes"], "a process was taken for lost during a 3 s cut"
print("PASS")
PY
