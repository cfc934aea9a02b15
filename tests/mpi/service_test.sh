#!/usr/bin/env bash
# The rendering service against a real running job (deploy/run.sh --serve):
#   service_test.sh BIN_DIR DATASET PYTHON_MODULES SCENARIO
# SCENARIO:
#   clients   several clients at once (one slow reader, one that never reads)
#             all get their frames, equal to the reference renderer's; a
#             shutdown request ends every process
#   bad       each kind of bad message gets an error reply and changes
#             nothing; newer cameras supersede queued ones; a reader slower
#             than its render requests' frames still gets every one; a path
#             reader the job outruns learns its frames were dropped; the job
#             serves on
#   options   live options: two clients at once, one drawing splats at 2 px,
#             the other the job's points; then blended under a scheduler
#             switched to round-robin; every frame equals the reference
#             renderer's for its mode and level of detail
#   render-cache  the display's render cache (on by default in serve mode): a
#             client moving the camera one render request at a time gets an
#             interim frame before each final one after the first, close to
#             it; final frames still equal the reference renderer's; path
#             frames get none; the same with --tile-priority none (tiles
#             out at once, reprojection after) and --interim-refresh-ms 0:
#             the interim frame goes again as tiles arrive, each time with
#             more tiles and never fewer pixels equal to the final frame's;
#             with --interim-ms -1 no interim frame comes
#   instanced a dataset built with --instanced: a client switches to the
#             instanced mode while another keeps points; info offers it;
#             both clients' frames equal the reference renderer's
#   statistical the same for a dataset built with --statistical and the
#             statistical mode
#   curve     CURVE with keys from files: an authorized client renders, a client
#             with another key or without CURVE gets nothing
#   sigint    SIGINT to the display: clean shutdown of every process
#   sigterm   SIGTERM to deploy/run.sh (what a batch scheduler sends): clean
#             shutdown of every process
#   mpirun-sigterm  SIGTERM to mpirun itself: Open MPI ends every process
# Environment: MIN_LIT_FRACTION, MIN_SPLATS (the scene's floors, as for the frames tests).
set -uo pipefail
BIN="$1" DATASET="$2" PYTHON_MODULES="$3" scenario="$4"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
source "$ROOT/tests/mpi/service_job.sh"
client=("$BIN/pointillist-client" --connect "$ENDPOINT" --timeout 30)
python=(env POINTILLIST_PYTHON="$PYTHON_MODULES" /usr/bin/python3)
: "${MIN_LIT_FRACTION:?}" "${MIN_SPLATS:?}"
floors=(--min-lit-fraction "$MIN_LIT_FRACTION" --min-splats "$MIN_SPLATS")

case "$scenario" in
  render-cache)
    start_service_job
    "${client[@]}" info >"$WORK/info.log" 2>&1 || fail "info: $(cat "$WORK/info.log")"
    grep -q "render cache: interim frames for render requests after 0 ms" "$WORK/info.log" ||
      fail "serve mode has no render cache: $(cat "$WORK/info.log")"
    "${client[@]}" orbit --camera-path orbit --frames 24 -o "$WORK/orbit" --csv "$WORK/orbit.csv" \
      >"$WORK/orbit.log" 2>&1 || fail "orbit: $(cat "$WORK/orbit.log")"
    grep -E "^(latency|interim frames|orbit)" "$WORK/orbit.log"
    # Every camera after the first had an interim frame, drawn before the final one.
    interims=$(awk -F, 'NR > 2 && $4 == 1' "$WORK/orbit.csv" | wc -l)
    ((interims == 23)) || fail "$interims of 23 cameras had an interim frame"
    awk -F, 'NR == 2 && $4 != 0 { exit 1 }' "$WORK/orbit.csv" ||
      fail "an interim frame came before any frame was cached"
    # Close to the final frame (15 degrees apart: most pixels reprojected).
    awk -F, 'NR > 2 && ($8 < 15 || $10 < 0.6) { print; bad = 1 } END { exit bad }' \
      "$WORK/orbit.csv" || fail "an interim frame is far from its final frame (PSNR, filled)"
    awk -F, 'NR > 2 && $3 > $2 { bad = 1 } END { exit bad }' "$WORK/orbit.csv" ||
      fail "an interim frame came after its final frame"
    "${client[@]}" path --camera-path flythrough --frames 3 >"$WORK/path.log" 2>&1 ||
      fail "path: $(cat "$WORK/path.log")"
    "${client[@]}" stats >"$WORK/stats.log" 2>&1 || fail "stats"
    cat "$WORK/stats.log"
    grep -q "^interim frames (render cache): 23$" "$WORK/stats.log" ||
      fail "path frames got interim frames, or interim frames were lost"
    echo "reference comparison of the final frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 24 \
      --size 480x270 --compare "$WORK/orbit" "${floors[@]}" || fail "final frames"
    "${client[@]}" shutdown --reason "test done" >/dev/null || fail "shutdown"
    wait_job_exit 60
    grep -E "^render cache:" "$JOB_LOG" || fail "the display's summary has no render cache line"
    # Tiles out at once, the reprojection while they are drawn: still an
    # interim frame for each camera after the first, and final frames exact.
    # Refreshed as the tiles come: the arriving tiles replace the cache's
    # pixels region by region.
    start_service_job --tile-priority none --interim-refresh-ms 0
    "${client[@]}" orbit --camera-path orbit --frames 8 -o "$WORK/at-once" \
      --csv "$WORK/at-once.csv" >"$WORK/at-once.log" 2>&1 ||
      fail "orbit with --tile-priority none: $(cat "$WORK/at-once.log")"
    grep -E "^(  [0-9]+ more|interim frames)" "$WORK/at-once.log"
    interims=$(awk -F, 'NR > 2 && $4 == 1' "$WORK/at-once.csv" | wc -l)
    ((interims == 7)) || fail "--tile-priority none: $interims of 7 cameras had an interim frame"
    awk -F, 'NR > 2 && $14 != 1 { print; bad = 1 } END { exit bad }' "$WORK/at-once.csv" ||
      fail "a later interim frame had no more tiles, or fewer pixels as final, than the one before"
    refreshed=$(awk -F, 'NR > 2 && $11 > 1' "$WORK/at-once.csv" | wc -l)
    ((refreshed > 0)) || fail "no interim frame went again with the tiles that came"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 8 \
      --size 480x270 --compare "$WORK/at-once" "${floors[@]}" ||
      fail "final frames with --tile-priority none"
    "${client[@]}" shutdown --reason "test done" >/dev/null || fail "shutdown"
    wait_job_exit 60
    # Without the cache: no interim frame.
    start_service_job --interim-ms -1
    "${client[@]}" orbit --camera-path orbit --frames 3 --csv "$WORK/off.csv" \
      >"$WORK/off.log" 2>&1 || fail "orbit without the cache: $(cat "$WORK/off.log")"
    awk -F, 'NR > 1 && $4 != 0 { exit 1 }' "$WORK/off.csv" ||
      fail "an interim frame came with --interim-ms -1"
    "${client[@]}" shutdown --reason "test done" >/dev/null || fail "shutdown"
    wait_job_exit 60
    ;;
  clients)
    # A small stream high-water mark, so the client that never reads fills its own stream.
    start_service_job --stream-hwm 4
    "${client[@]}" info >"$WORK/info.log" 2>&1 || fail "info: $(cat "$WORK/info.log")"
    cat "$WORK/info.log"
    # A camera the Python client asks for, given in the unit cube of the bounds;
    # the reference reads the same numbers from a camera-path file.
    echo "0.45 -0.05 0.35 0.5 0.5 0.05" >"$WORK/python-camera.txt"
    # The Python camera is in unit-cube coordinates of the bounds: map it.
    read -r x0 y0 z0 x1 y1 z1 < <(grep -Eo 'bounds \([^)]*\) - \([^)]*\)' "$WORK/info.log" |
      tr -d '(),' | awk '{print $2, $3, $4, $6, $7, $8}')
    awk -v x0="$x0" -v y0="$y0" -v z0="$z0" -v x1="$x1" -v y1="$y1" -v z1="$z1" '{
      printf "%.9g %.9g %.9g %.9g %.9g %.9g\n", x0 + $1 * (x1 - x0), y0 + $2 * (y1 - y0),
        z0 + $3 * (z1 - z0), x0 + $4 * (x1 - x0), y0 + $5 * (y1 - y0), z0 + $6 * (z1 - z0) }' \
      "$WORK/python-camera.txt" >"$WORK/python-camera-world.txt"
    camera=$(tr ' ' ',' <"$WORK/python-camera-world.txt")
    "${client[@]}" --name never-reads path --camera-path orbit --frames 60 --never-read \
      --frame-timeout 600 >"$WORK/never.log" 2>&1 &
    never=$!
    "${client[@]}" --name fast path --camera-path orbit --frames 4 -o "$WORK/fast" \
      >"$WORK/fast.log" 2>&1 &
    fast=$!
    "${client[@]}" --name slow path --camera-path flythrough --frames 4 --read-delay-ms 700 \
      -o "$WORK/slow" >"$WORK/slow.log" 2>&1 &
    slow=$!
    mkdir -p "$WORK/python"
    "${python[@]}" "$ROOT/clients/python/pointillist_client.py" --connect "$ENDPOINT" render \
      --camera="$camera" -o "$WORK/python/frame_00000.png" \
      >"$WORK/python.log" 2>&1 &
    py=$!
    code=0
    for pid in $fast $slow $py; do wait "$pid" || code=1; done
    for name in fast slow python; do echo "--- $name client"; cat "$WORK/$name.log"; done
    ((code == 0)) || fail "a client did not get its frames"
    kill -0 "$never" 2>/dev/null || fail "the client that never reads has ended: $(cat "$WORK/never.log")"
    # Its frames are rendered (the others' came in between) and, its stream full, dropped.
    for _ in $(seq 1 120); do
      "${client[@]}" stats >"$WORK/stats.log" || fail "stats"
      grep -Eq '\(never-reads\): .* 0 queued' "$WORK/stats.log" && break
      sleep 0.5
    done
    cat "$WORK/stats.log"
    grep -Eq '\(never-reads\): [0-9]+ frames sent, [1-9][0-9]* dropped' "$WORK/stats.log" ||
      fail "the client that never reads lost no frames: its stream is not bounded"
    kill "$never" 2>/dev/null; wait "$never" 2>/dev/null
    echo "reference comparisons"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 4 \
      --size 480x270 --compare "$WORK/fast" "${floors[@]}" || fail "fast client's frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path flythrough --frames 4 \
      --size 480x270 --compare "$WORK/slow" "${floors[@]}" || fail "slow client's frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path "$WORK/python-camera-world.txt" \
      --size 480x270 --compare "$WORK/python" "${floors[@]}" || fail "python client's frame"
    "${client[@]}" shutdown --reason "test done" || fail "shutdown request"
    wait_job_exit 60
    cat "$JOB_LOG"
    ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
    grep -q "service stopped (shutdown requested by client pointillist-client: test done)" \
      "$JOB_LOG" || fail "no service stop line"
    grep -q "shutdown complete" "$JOB_LOG" || fail "no clean shutdown"
    assert_nothing_left
    ;;
  options)
    start_service_job
    "${client[@]}" --name splats --mode splats --lod-pixels 2 path --camera-path orbit \
      --frames 3 -o "$WORK/splats" >"$WORK/splats.log" 2>&1 &
    splats=$!
    "${client[@]}" --name points path --camera-path orbit --frames 3 -o "$WORK/points" \
      >"$WORK/points.log" 2>&1 &
    points=$!
    code=0
    for pid in $splats $points; do wait "$pid" || code=1; done
    for name in splats points; do echo "--- $name client"; cat "$WORK/$name.log"; done
    ((code == 0)) || fail "a client did not get its frames"
    grep -q "drawn as splats, lod 2 px, scheduler cost" "$WORK/splats.log" ||
      fail "the splats client's frames were not drawn as it asked"
    grep -q "drawn as points, lod 1 px, scheduler cost" "$WORK/points.log" ||
      fail "the points client's frames changed with the other client's options"
    "${client[@]}" --name blended --mode blended --scheduler round-robin path \
      --camera-path flythrough --frames 3 -o "$WORK/blended" >"$WORK/blended.log" 2>&1 ||
      fail "blended frames: $(cat "$WORK/blended.log")"
    cat "$WORK/blended.log"
    grep -q "drawn as blended, lod 1 px, scheduler round-robin" "$WORK/blended.log" ||
      fail "the blended frames were not drawn as asked"
    "${client[@]}" info >"$WORK/info.log" 2>&1 || fail "info"
    grep -q "scheduler round-robin" "$WORK/info.log" || fail "info does not show the new scheduler"
    echo "reference comparisons"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 3 \
      --size 480x270 --mode splats --lod-pixels 2 --compare "$WORK/splats" "${floors[@]}" ||
      fail "splats client's frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 3 \
      --size 480x270 --compare "$WORK/points" "${floors[@]}" || fail "points client's frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path flythrough --frames 3 \
      --size 480x270 --mode blended --compare "$WORK/blended" "${floors[@]}" ||
      fail "blended client's frames"
    "${client[@]}" shutdown || fail "shutdown request"
    wait_job_exit 60
    ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
    assert_nothing_left
    ;;
  instanced | statistical)
    # A dataset built with --instanced (--statistical), a points job: one
    # client switches to that mode, another keeps points; both get the
    # reference's frames.
    mode="$scenario"
    start_service_job
    "${client[@]}" --name "$mode" --mode "$mode" path --camera-path orbit --frames 3 \
      -o "$WORK/$mode" >"$WORK/$mode.log" 2>&1 ||
      fail "$mode frames: $(cat "$WORK/$mode.log")"
    cat "$WORK/$mode.log"
    grep -q "drawn as $mode, lod 1 px" "$WORK/$mode.log" ||
      fail "the $mode frames were not drawn as asked"
    "${client[@]}" --name points path --camera-path orbit --frames 3 -o "$WORK/points" \
      >"$WORK/points.log" 2>&1 || fail "points frames: $(cat "$WORK/points.log")"
    "${client[@]}" info >"$WORK/info.log" 2>&1 || fail "info"
    grep -Eq "available: points, splats, blended(, instanced)?(, statistical)?" "$WORK/info.log" &&
      grep -q "available: .*$mode" "$WORK/info.log" ||
      fail "info does not offer the $mode mode: $(cat "$WORK/info.log")"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 3 \
      --size 480x270 --mode "$mode" --compare "$WORK/$mode" "${floors[@]}" ||
      fail "$mode client's frames"
    "$BIN/pointillist-reference" --dataset "$DATASET" --camera-path orbit --frames 3 \
      --size 480x270 --compare "$WORK/points" "${floors[@]}" || fail "points client's frames"
    "${client[@]}" shutdown || fail "shutdown request"
    wait_job_exit 60
    ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
    assert_nothing_left
    ;;
  bad)
    # The cpu renderer draws points only: a client asking for splats is refused.
    start_service_job --stream-hwm 4 --renderer cpu
    "${python[@]}" "$ROOT/tests/mpi/service_bad_requests.py" "$ENDPOINT" || fail "bad requests"
    # A path reader the job outruns (its stream holds 4 frames): it is told how
    # many frames were dropped instead of waiting for them until its timeout.
    start=$SECONDS
    "${client[@]}" --name outrun --encoding raw path --camera-path orbit --frames 40 \
      --read-delay-ms 250 --frame-timeout 200 >"$WORK/outrun.log" 2>&1
    outrun=$?
    took=$((SECONDS - start))
    cat "$WORK/outrun.log"
    "${client[@]}" stats >"$WORK/stats.log" || fail "stats"
    dropped=$(grep -Eo '\(outrun\): [0-9]+ frames sent, [0-9]+ dropped' "$WORK/stats.log" |
      grep -Eo '[0-9]+ dropped' | grep -Eo '[0-9]+')
    [[ -n "$dropped" ]] || fail "no statistics for the outrun client"
    if ((dropped > 0)); then
      ((outrun == 1)) || fail "the outrun client lost $dropped frames and exited $outrun"
      grep -q "$dropped of 40 frames were dropped" "$WORK/outrun.log" ||
        fail "the outrun client did not say how many frames were dropped"
      ((took < 60)) || fail "the outrun client waited $took s for dropped frames"
      echo "the outrun client lost $dropped frames, said so and ended after $took s"
    else
      ((outrun == 0)) || fail "no frame was dropped, yet the client exited $outrun"
      echo "this time the client kept up (no frame dropped)"
    fi
    # Still serving after all of it.
    "${client[@]}" render --camera 0,0,1,0.1,0.1,0 -o "$WORK/after.png" ||
      fail "the job stopped serving"
    "${client[@]}" shutdown || fail "shutdown request"
    wait_job_exit 60
    ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
    assert_nothing_left
    ;;
  curve)
    for who in server alice mallory; do
      "$BIN/pointillist-client" keygen "$WORK/$who" >/dev/null || fail "keygen $who"
    done
    { echo "# alice"; cat "$WORK/alice.public"; } >"$WORK/authorized"
    start_service_job --curve-secret-key "$WORK/server.secret" \
      --curve-authorized-keys "$WORK/authorized"
    grep -q "service listening on .*CURVE" "$JOB_LOG" || fail "the service is not on CURVE"
    bare=("$BIN/pointillist-client" --connect "$ENDPOINT" --timeout 3)
    alice=("${client[@]}" --curve-server-key "$WORK/server.public" --curve-key "$WORK/alice.secret")
    "${alice[@]}" render --camera=0,-400,200,0,0,0 -o "$WORK/alice.png" ||
      fail "an authorized client got no frame"
    if "${bare[@]}" --curve-server-key "$WORK/server.public" --curve-key "$WORK/mallory.secret" \
      info; then
      fail "a client whose key is not authorized was answered"
    fi
    if "${bare[@]}" info; then fail "a client without CURVE was answered"; fi
    grep -q "refused a connection" "$JOB_LOG" || fail "no refusal in the job's log"
    "${alice[@]}" stats || fail "the authorized client lost its service"
    # The Python client with the same keys.
    "${python[@]}" "$ROOT/clients/python/pointillist_client.py" --connect "$ENDPOINT" \
      --curve-server-key "$WORK/server.public" --curve-key "$WORK/alice.secret" render \
      --camera=0,-400,200,0,0,0 -o "$WORK/alice-python.png" || fail "the Python client with CURVE"
    [[ -s "$WORK/alice-python.png" ]] || fail "the Python client wrote no frame"
    if "${python[@]}" "$ROOT/clients/python/pointillist_client.py" --connect "$ENDPOINT" \
      --timeout 3 --curve-server-key "$WORK/server.public" --curve-key "$WORK/mallory.secret" \
      info; then
      fail "a Python client whose key is not authorized was answered"
    fi
    "${alice[@]}" shutdown || fail "shutdown request"
    wait_job_exit 60
    ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE"
    assert_nothing_left
    ;;
  sigint | sigterm | mpirun-sigterm)
    start_service_job
    "${client[@]}" path --camera-path orbit --frames 2 || fail "frames before the signal"
    case "$scenario" in
      sigint)
        display=$(pgrep -f -- "^[^ ]*/pointillist-display .*$WORK" | head -n1)
        [[ -n "$display" ]] || fail "no display process"
        kill -INT "$display"
        ;;
      sigterm) kill -TERM "$JOB_PID" ;;  # deploy/run.sh
      mpirun-sigterm)
        mpirun=$(pgrep -f -- "^mpirun.*$WORK" | head -n1)
        [[ -n "$mpirun" ]] || fail "no mpirun process"
        kill -TERM "$mpirun"
        ;;
    esac
    wait_job_exit 60
    cat "$JOB_LOG"
    echo "--- job exit code $JOB_CODE"
    if [[ "$scenario" != mpirun-sigterm ]]; then
      ((JOB_CODE == 0)) || fail "the job exited with $JOB_CODE after $scenario"
      grep -q "service stopped (SIGINT)" "$JOB_LOG" || fail "no service stop line"
      grep -q "shutdown complete" "$JOB_LOG" || fail "no clean shutdown"
    fi
    assert_nothing_left
    ;;
  *)
    echo "unknown scenario $scenario" >&2
    exit 2
    ;;
esac
echo PASS
