#!/usr/bin/env bash
# The display's render cache (seed 001), by hand (not in ctest): for each
# scene, a serve-mode job with the cache and one without; one client moves the
# camera along the `turns` path (fast swings, up to ten degrees a frame at 48
# frames), sending each camera when the last final frame came, as a person
# dragging the view. Prints, with and without the cache: time from camera
# change to the first frame shown (median, 95th percentile) and to the final
# frame; with it: PSNR of each interim frame against its final frame, the share
# of the final frame's covered pixels the interim one filled, and the time to
# reproject. Plots the time to first frame per camera. Four cases per scene:
# off (--interim-ms -1), on (the paper's: each camera reprojected before its
# tiles go out, the tiles the cache could not fill first), on-np
# (--tile-priority none: the tiles go out at once, the reprojection runs
# while they are drawn) and refresh (as on, and the interim frame goes again
# as tiles arrive, --interim-refresh-ms as --refresh-ms: the columns
# "updates", interim frames per camera, and "final px %", the share of pixels
# equal to the final frame's in the last interim one). First, pointillist-bench-render-cache times the cache
# alone on one core (a toy city cast by rays, fully covered and a quarter
# covered frame) and its lines open the table.
#
#   deploy/bench-render-cache.sh [--scenes city,bunny-10M] [--frames 48] [--layout 1,2,1,4]
#       [--size 1280x720] [--path turns] [--cases off,on,on-np,refresh] [--refresh-ms 5]
#
# Scenes: city is the built-in city (2 M points); bunny-10M is Debian's
# bunny00.off (libcgal-demo) sampled to 10 M points (made on first use, as
# deploy/bench-speed.sh does). Output in out/bench-render-cache/.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

scenes="city,bunny-10M"
frames=48
layout="1,2,1,4"
size="1280x720"
path="turns"
cases="off,on,on-np,refresh"
refresh_ms=5
while (($#)); do
  case "$1" in
    --scenes) scenes="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --path) path="$2"; shift 2 ;;
    --cases) cases="$2"; shift 2 ;;
    --refresh-ms) refresh_ms="$2"; shift 2 ;;
    -h|--help) awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) echo "bench-render-cache.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
build_all
out="${BENCH_OUT:-$POINTILLIST_ROOT/out/bench-render-cache}"
mkdir -p "$out"

# Runs one job (display options as given) and the client; leaves LOG and CSV.
run_case() {
  local dataset="$1" tag="$2" work job endpoint
  shift 2
  work=$(mktemp -d /tmp/pointillist-bench-cache.XXXXXX)
  endpoint="ipc://$work/control"
  setsid bash "$POINTILLIST_ROOT/deploy/run.sh" --layout "$layout" --dataset "$dataset" --serve \
    --listen "$endpoint" --size "$size" "$@" --quiet >"$out/$tag-job.log" 2>&1 &
  job=$!
  for _ in $(seq 1 600); do
    grep -q "service listening on" "$out/$tag-job.log" && break
    kill -0 "$job" 2>/dev/null || { cat "$out/$tag-job.log" >&2; exit 1; }
    sleep 0.2
  done
  local client=("$POINTILLIST_BIN/pointillist-client" --connect "$endpoint" --timeout 60
    --size "$size" --encoding raw)
  # Once round first: the render processes' data caches warm, as for a user
  # after a moment (the render cache is warm from the first camera on anyway).
  "${client[@]}" orbit --camera-path "$path" --frames "$frames" >/dev/null 2>>"$out/clients.err"
  "${client[@]}" orbit --camera-path "$path" --frames "$frames" --csv "$out/$tag.csv" \
    >"$out/$tag.log" 2>>"$out/clients.err"
  "${client[@]}" stats >"$out/$tag-stats.txt" 2>>"$out/clients.err"
  "${client[@]}" shutdown >/dev/null 2>>"$out/clients.err"
  wait "$job" || true
  rm -rf "$work"
}

# Median and 95th percentile of CSV column COL (1-based) over rows where
# column FILTER (if given) is 1.
stats_of() {
  awk -F, -v col="$2" -v filter="${3:-0}" 'NR > 1 && (filter == 0 || $filter == 1) { print $col }' "$1" |
    sort -g | awk '{ v[NR] = $1 } END {
      if (NR == 0) { printf "%8s %8s", "-", "-"; exit }
      m = (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2
      p = v[int(0.95 * (NR - 1)) + 1]
      printf "%8.1f %8.1f", m, p }'
}

: >"$out/clients.err"
table="$out/table.txt"
{
  for coverage in 1 0.25; do
    "$POINTILLIST_BIN/pointillist-bench-render-cache" --size "$size" --coverage "$coverage" \
      --reps 100
  done
  echo
  printf '%-10s %-8s | %17s | %17s | %7s %13s %12s %12s %8s %11s\n' scene cache \
    "first shown ms" "final ms" interims "PSNR dB (med)" "filled %" "reproject ms" updates \
    "final px %"
  printf '%-10s %-8s | %8s %8s | %8s %8s |\n' "" "" median p95 median p95
} >"$table"
IFS=',' read -r -a scene_list <<<"$scenes"
for scene in "${scene_list[@]}"; do
  dataset=$(scene_dataset "$scene")
  IFS=',' read -r -a case_list <<<"$cases"
  for case_name in "${case_list[@]}"; do
    tag="$scene-$case_name"
    log "$scene: render cache $case_name"
    case "$case_name" in
      off) run_case "$dataset" "$tag" --interim-ms -1 ;;
      on) run_case "$dataset" "$tag" --interim-ms 0 --tile-priority cache ;;
      on-np) run_case "$dataset" "$tag" --interim-ms 0 --tile-priority none ;;
      refresh) run_case "$dataset" "$tag" --interim-ms 0 --tile-priority cache \
        --interim-refresh-ms "$refresh_ms" ;;
      *) echo "bench-render-cache.sh: unknown case $case_name" >&2; exit 2 ;;
    esac
    csv="$out/$tag.csv"
    count=$(awk -F, 'NR > 1 && $4 == 1' "$csv" | wc -l)
    psnr=$(stats_of "$csv" 8 4 | awk '{print $1}')
    filled=$(awk -F, 'NR > 1 && $4 == 1 { print $10 * 100 }' "$csv" | sort -g |
      awk '{ v[NR] = $1 } END { if (NR) printf "%.1f", (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2; else printf "-" }')
    reproject=$(stats_of "$csv" 6 4 | awk '{print $1}')
    updates=$(awk -F, 'NR > 1 && $4 == 1 { n++; s += $11 } END { if (n) printf "%.2f", s / n; else printf "-" }' "$csv")
    final_px=$(awk -F, 'NR > 1 && $4 == 1 { print $13 * 100 }' "$csv" | sort -g |
      awk '{ v[NR] = $1 } END { if (NR) printf "%.1f", (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2; else printf "-" }')
    printf '%-10s %-8s | %s | %s | %7s %13s %12s %12s %8s %11s\n' "$scene" \
      "$case_name" "$(stats_of "$csv" 3)" \
      "$(stats_of "$csv" 2)" "$count/$frames" "$psnr" "$filled" "$reproject" "$updates" \
      "$final_px" >>"$table"
  done
done
echo "on-np: --tile-priority none (tiles at once, reprojection while they are drawn)" >>"$table"
echo "refresh: as on, with --interim-refresh-ms $refresh_ms (the interim frame again as tiles arrive)" >>"$table"
echo
cat "$table"
if command -v gnuplot >/dev/null; then
  plots=""
  for scene in "${scene_list[@]}"; do
    for case_name in "${case_list[@]}"; do
      case "$case_name" in
        off) title="no cache" ;;
        on) title="render cache" ;;
        on-np) title="cache, tiles at once" ;;
        refresh) title="cache, refreshed" ;;
      esac
      plots+="\"$out/$scene-$case_name.csv\" using 1:3 with linespoints title \"$scene, $title\", "
    done
  done
  gnuplot <<PLOT
set terminal pngcairo size 1000,560 font "sans,11" noenhanced
set output "$out/first-shown.png"
set datafile separator ","
set title "Camera change to first frame shown, path $path, $size, layout $layout"
set xlabel "camera of the path"
set ylabel "milliseconds"
set yrange [0:*]
set key top left
set grid
plot ${plots%, }
PLOT
  echo "plot: $out/first-shown.png"
fi
echo "logs and CSV in $out"
