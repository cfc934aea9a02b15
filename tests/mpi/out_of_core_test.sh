#!/usr/bin/env bash
# The out-of-core preprocess from the command line (issue 13):
#  - forced by a tiny --memory-mb on a small input it writes the in-memory
#    run's dataset file for file, and stays under the cap (peak resident memory
#    measured from outside, by the parent's rusage);
#  - that dataset renders the in-memory dataset's frames (reference renderer),
#    and a real job's frames equal the reference's on it;
#  - its temporary files are gone after success, after a failure midway and
#    after SIGTERM, and the failed or stopped runs leave no dataset.
#   out_of_core_test.sh BIN_DIR COMPARE_WITH_REFERENCE_SH
set -euo pipefail
bin="$1" compare="$2"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cap=40

"$bin/pointillist-make-points" --generate city --points 400000 -o "$work/city.ply" 2>/dev/null
"$bin/pointillist-preprocess" -q "$work/city.ply" -o "$work/memory" > "$work/memory.log"
if grep -q "out of core" "$work/memory.log"; then exit 1; fi

# Runs a command with its output in LOG and prints its peak resident memory
# in MiB, measured from outside:  peakMiB LOG COMMAND...
peakMiB() {
  python3 -c '
import resource, subprocess, sys
with open(sys.argv[1], "w") as log:
    subprocess.run(sys.argv[2:], check=True, stdout=log)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024)
' "$@"
}
peakMiB "$work/chunked.log" "$bin/pointillist-preprocess" -q "$work/city.ply" -o "$work/chunked" \
  --memory-mb "$cap" > "$work/peak"
cat "$work/chunked.log"
chunks=$(sed -n 's/.*out of core: \([0-9]*\) chunks.*/\1/p' "$work/chunked.log")
echo "out of core: $chunks chunks, peak $(cat "$work/peak") MiB under --memory-mb $cap"
test "$chunks" -ge 3
test "$(cat "$work/peak")" -le "$cap"
for f in manifest.txt cells.bin top-level.bin packet-checksums.bin points.bin; do
  cmp "$work/memory/$f" "$work/chunked/$f"
done
"$bin/pointillist-preprocess" --check "$work/chunked" | grep -q "400000 points"

# Frames: the reference renderer on both datasets, and a job on the chunked one.
"$bin/pointillist-reference" --dataset "$work/memory" --camera-path orbit --frames 3 \
  --size 320x180 --out "$work/frames" > /dev/null
"$bin/pointillist-reference" --dataset "$work/chunked" --camera-path orbit --frames 3 \
  --size 320x180 --compare "$work/frames" --min-lit-fraction 0.1 --min-splats 30000
MIN_LIT_FRACTION=0.1 MIN_SPLATS=30000 bash "$compare" "$bin" "$work/chunked" 1,1,1,2 orbit 3 \
  320x180 points

leftovers() { find "$work" -maxdepth 1 \( -name '*.spill-*' -o -name '*.tmp-*' \) | wc -l; }
test "$(leftovers)" -eq 0

# A scan without normals (XYZ text): its normals are estimated chunk by chunk,
# with neighbours across chunk borders and a side reference, still under the
# cap (unit tests compare the sides with the in-memory run's).
"$bin/pointillist-make-points" --generate city --points 400000 --format xyz --no-normals \
  -o "$work/scan.xyz" 2>/dev/null
peakMiB "$work/scan.log" "$bin/pointillist-preprocess" -q "$work/scan.xyz" -o "$work/scan" \
  --memory-mb "$cap" > "$work/scan-peak"
cat "$work/scan.log"
scanChunks=$(sed -n 's/.*out of core: \([0-9]*\) chunks.*/\1/p' "$work/scan.log")
echo "scan without normals: $scanChunks chunks, peak $(cat "$work/scan-peak") MiB under --memory-mb $cap"
test "$scanChunks" -ge 3
test "$(cat "$work/scan-peak")" -le "$cap"
"$bin/pointillist-preprocess" --check "$work/scan" | grep -q "400000 points"
rm -rf "$work/scan" "$work/scan.xyz"
test "$(leftovers)" -eq 0

# --generate builds its scene in memory: over the cap it is refused at once.
if "$bin/pointillist-preprocess" -q --generate city --points 2000000 -o "$work/generated" \
  --memory-mb "$cap" 2> "$work/generated.log"; then
  exit 1
fi
grep -q "builds its scene in memory" "$work/generated.log"
test ! -e "$work/generated"
test "$(leftovers)" -eq 0

# A failure midway (after two chunks) leaves nothing.
if POINTILLIST_PREPROCESS_FAIL_AFTER_CHUNKS=2 "$bin/pointillist-preprocess" -q "$work/city.ply" \
  -o "$work/failed" --memory-mb "$cap" 2> "$work/failed.log"; then
  exit 1
fi
grep -q "failing on purpose after 2 chunk" "$work/failed.log"
test ! -e "$work/failed"
test "$(leftovers)" -eq 0

# SIGTERM once spill files exist: exit 130, nothing left.
"$bin/pointillist-preprocess" "$work/city.ply" -o "$work/stopped" --memory-mb "$cap" \
  2> "$work/stopped.log" &
pid=$!
for _ in $(seq 1 500); do
  if compgen -G "$work/stopped.spill-*/cell-*" > /dev/null; then break; fi
  sleep 0.01
done
compgen -G "$work/stopped.spill-*/cell-*" > /dev/null
kill -TERM "$pid"
rc=0
wait "$pid" || rc=$?
cat "$work/stopped.log"
test "$rc" -eq 130
grep -q "interrupted" "$work/stopped.log"
test ! -e "$work/stopped"
test "$(leftovers)" -eq 0
echo "out-of-core: same dataset and frames, under the cap, nothing left behind"
