#!/usr/bin/env bash
# Latency of the rendering service, by hand (not in ctest): starts a serve-mode
# job on the built-in city, then for each encoding asks for one frame at a
# time round an orbit at 1280x720 (the next camera once the last frame came)
# and prints the median and 95th percentile from camera request to frame
# received, and the frames/s that single client sustains; then the frames/s of
# a path request (the job pipelines its frames; a stream of 64 frames, so a
# client the job outruns loses none). Plots the latency per frame.
#
#   deploy/bench-service.sh [--frames N] [--layout D,T,S,R] [--dataset DIR] [--points N]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
frames=48
layout="1,2,1,4"
points=2000000
dataset=""
while (($#)); do
  case "$1" in
    --frames) frames="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --dataset) dataset="$2"; shift 2 ;;
    --points) points="$2"; shift 2 ;;
    -h|--help) sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench-service.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
if [[ -z "$dataset" ]]; then
  dataset="$POINTILLIST_ROOT/datasets/city-$points"
  ensure_city_dataset "$dataset" "$points"
fi
out="${BENCH_OUT:-$POINTILLIST_ROOT/out/bench-service/$(basename "$dataset")}"
mkdir -p "$out"
work=$(mktemp -d /tmp/pointillist-bench-service.XXXXXX)
endpoint="ipc://$work/control"
client=("$POINTILLIST_BIN/pointillist-client" --connect "$endpoint" --timeout 60 --size 1280x720)
quiet_client() { "${client[@]}" "$@" 2>>"$out/clients.err" || { cat "$out/clients.err" >&2; return 1; }; }
: >"$out/clients.err"
setsid bash "$POINTILLIST_ROOT/deploy/run.sh" --layout "$layout" --dataset "$dataset" --serve \
  --listen "$endpoint" --size 1280x720 --stream-hwm 64 --interim-ms -1 --quiet >"$out/job.log" 2>&1 &
job=$!
trap 'kill -KILL -- -$job 2>/dev/null || true; rm -rf "$work"' EXIT
for _ in $(seq 1 600); do
  grep -q "service listening on" "$out/job.log" && break
  kill -0 "$job" 2>/dev/null || { cat "$out/job.log"; exit 1; }
  sleep 0.2
done
quiet_client info
# One orbit first so caches are warm, as they are for a user after a moment.
quiet_client --encoding raw orbit --frames "$frames" >/dev/null
printf '\n%-6s %12s %12s %12s %14s\n' encoding "median ms" "p95 ms" "frames/s" "KiB per frame"
for encoding in raw png jpeg; do
  quiet_client --encoding "$encoding" orbit --frames "$frames" >"$out/orbit-$encoding.log"
  summary=$(grep -E '^latency request to final frame' "$out/orbit-$encoding.log")
  median=$(grep -Eo 'median [0-9.]+' <<<"$summary" | grep -Eo '[0-9.]+$')
  p95=$(grep -Eo 'p95 [0-9.]+' <<<"$summary" | grep -Eo '[0-9.]+$')
  rate=$(grep -Eo '[0-9.]+ frames/s' "$out/orbit-$encoding.log" | grep -Eo '^[0-9.]+')
  kib=$(grep -Eo '[0-9.]+ KiB' "$out/orbit-$encoding.log" | grep -Eo '^[0-9.]+' |
    awk '{s += $1; n++} END {printf "%.0f", n ? s / n : 0}')
  printf '%-6s %12s %12s %12s %14s\n' "$encoding" "$median" "$p95" "$rate" "$kib"
done
echo
for encoding in raw png jpeg; do
  quiet_client --encoding "$encoding" path --camera-path orbit --frames "$frames" \
    >"$out/path-$encoding.log"
  echo "path request, $encoding: $(grep -E '^path:' "$out/path-$encoding.log")"
done
# Latency of each orbit frame per encoding, drawn.
for encoding in raw png jpeg; do
  grep -Eo 'latency [0-9.]+ ms' "$out/orbit-$encoding.log" | awk '{print NR, $2}' \
    >"$out/latency-$encoding.dat"
done
if command -v gnuplot >/dev/null; then
  gnuplot <<PLOT
set terminal pngcairo size 1000,560 font "sans,11" noenhanced
set output "$out/latency.png"
set title "Camera request to frame received, one client orbiting, 1280x720 ($(basename "$dataset"), layout $layout)"
set xlabel "frame of the orbit"
set ylabel "latency (ms)"
set yrange [0:*]
set key top left
set grid
plot "$out/latency-raw.dat" with linespoints title "raw RGBA", \
     "$out/latency-png.dat" with linespoints title "PNG", \
     "$out/latency-jpeg.dat" with linespoints title "JPEG"
PLOT
  echo "plot: $out/latency.png"
fi
echo
quiet_client stats | tee "$out/stats.txt"
quiet_client shutdown >/dev/null
wait "$job" || true
echo "logs in $out"
