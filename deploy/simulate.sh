#!/usr/bin/env bash
# Scheduler simulator sweep: predicts frame rate, imbalance, bytes moved per
# frame and the bottleneck for 8 to 1024 render processes and several traverse
# counts, per scheduler, by driving the roles' own decision cores (display,
# traverse, data-send, render) with modelled time and network
# (pointillist-simulate; no MPI job is started). Prints the table with the
# model's assumptions, then a recommended layout (T, S) per scheduler and R:
# the fewest traverse and data-send processes within 5 % of the best frame
# rate swept, and what limits the job there (traverse, display, network,
# render or round trips).
#
#   deploy/simulate.sh [--dataset D] [--camera-path orbit] [--frames 16] [--size 1280x720]
#       [--renders 8,16,...,1024] [--traverses 1,2,4,8] [--datasends auto]
#       [--scheduler cost,regions,round-robin,static,equalizer] [--calibrate RUN_DIR]
#       [--points N] [--out DIR] [-- more pointillist-simulate options]
#
# --dataset defaults to datasets/city-N (N = --points, default 2000000), the
# built-in city scene, generated first when it is not there. --calibrate fits
# the render's time per packet, per pixel and per splat (T_p, T_px, T_s) to
# every tile drawn in a deploy/bench-loadbalance.sh output directory (the
# defaults are the CPU point kernel's on the development machine; OSMesa
# points: -- --seconds-per-splat 2e-7 --packet-overhead-ms 1
# --packet-ns-per-pixel 0); other rates are options of pointillist-simulate (see its --help),
# e.g. -- --bandwidth-mbs 1170 --latency-us 5 --cost-model overlap,paper, or
# -- --display-bandwidth-mbs 1170 (the display on 10 GbE, the rest on 1 GbE)
# --tile-tasks-ahead 1 (each traverse asks for one tile at a time, as before;
# the default, auto, keeps one request per 16 tiles a traverse walks per frame,
# 2 to 8). Tile images are sized by the pixels each frame lights: the
# dataset's points are read and every frame drawn once by the CPU point
# kernel (-- --lit-pixels off: a pixel a splat, capped by the box, as before
# 2026-12-02). A run whose tiles wait at the display for requests while the
# traverses idle is reported request-bound ("requests") in the table and advice.
# OUT (default out/simulate) gets simulate.csv (every figure, raw units),
# report.md (assumptions, table, plots), table.txt (what is printed) and:
#   fps.png        steady frames/s vs render processes, one line per scheduler
#   imbalance.png  max/mean busy time over render processes per frame
#   bytes.png      cell data sent to render processes per steady frame
# (one panel per traverse count, render processes on a log2 axis).
# Environment: POINTILLIST_BUILD (default build-release), POINTILLIST_BUILD_TYPE
# (default Release; used when the build directory is configured).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export POINTILLIST_BUILD="${POINTILLIST_BUILD:-$root/build-release}"
export POINTILLIST_BUILD_TYPE="${POINTILLIST_BUILD_TYPE:-Release}"
source "$root/deploy/common.sh"

me="simulate"
die() { printf '%s: %s\n' "$me" "$*" >&2; exit 2; }
say() { printf '%s: %s\n' "$me" "$*" >&2; }
usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "${BASH_SOURCE[0]}"; }

dataset=""
camera="orbit"
frames=16
size="1280x720"
renders="8,16,32,64,128,256,512,1024"
traverses="1,2,4,8"
datasends="auto"
schedulers="cost,regions,round-robin,static,equalizer"
calibrate=""
points=2000000
out="out/simulate"
sim_args=()
while (($#)); do
  case "$1" in
    --dataset|--camera-path|--frames|--size|--renders|--traverses|--datasends|--scheduler|--calibrate|--points|--out)
      (($# >= 2)) || die "$1 needs a value (see --help)"
      case "$1" in
        --dataset) dataset="$2" ;;
        --camera-path) camera="$2" ;;
        --frames) frames="$2" ;;
        --size) size="$2" ;;
        --renders) renders="$2" ;;
        --traverses) traverses="$2" ;;
        --datasends) datasends="$2" ;;
        --scheduler) schedulers="$2" ;;
        --calibrate) calibrate="$2" ;;
        --points) points="$2" ;;
        --out) out="$2" ;;
      esac
      shift 2 ;;
    --) shift; sim_args+=("$@"); break ;;
    -h|--help) usage; exit 0 ;;
    *) die "unknown option '$1' (simulator options go after --; see --help)" ;;
  esac
done

counts_re='^[1-9][0-9]*(,[1-9][0-9]*)*$'
[[ "$frames" =~ ^[1-9][0-9]*$ ]] || die "--frames '$frames' is not a positive count"
[[ "$size" =~ ^[1-9][0-9]*x[1-9][0-9]*$ ]] || die "--size '$size' is not WIDTHxHEIGHT"
[[ "$renders" =~ $counts_re ]] || die "--renders '$renders' is not a comma-separated list of counts"
[[ "$traverses" =~ $counts_re ]] || die "--traverses '$traverses' is not a comma-separated list of counts"
[[ "$datasends" == auto || "$datasends" =~ $counts_re ]] ||
  die "--datasends '$datasends' is not 'auto' or a comma-separated list of counts"
[[ "$schedulers" =~ ^[a-z-]+(,[a-z-]+)*$ ]] ||
  die "--scheduler '$schedulers' is not a comma-separated list of names (cost,round-robin,static,equalizer)"
[[ "$points" =~ ^[1-9][0-9]*$ ]] || die "--points '$points' is not a positive count"
if [[ -n "$calibrate" && ! -d "$calibrate" ]]; then
  die "--calibrate '$calibrate' is not a directory (give a deploy/bench-loadbalance.sh output directory)"
fi
if [[ -n "$dataset" && ! -f "$dataset/manifest.txt" ]]; then
  die "dataset '$dataset' is not a preprocessed dataset (no manifest.txt; make one with pointillist-preprocess)"
fi

install_packages
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
if [[ ! -f "$POINTILLIST_BUILD/CMakeCache.txt" ]]; then
  log "configuring a $POINTILLIST_BUILD_TYPE build in $POINTILLIST_BUILD"
  cmake -S "$POINTILLIST_ROOT" -B "$POINTILLIST_BUILD" -DCMAKE_BUILD_TYPE="$POINTILLIST_BUILD_TYPE" \
    -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
build_all
[[ -x "$POINTILLIST_BIN/pointillist-simulate" ]] ||
  die "$POINTILLIST_BIN/pointillist-simulate was not built (is simulator/ in the top-level CMakeLists.txt?)"
build_type="$(sed -n 's/^CMAKE_BUILD_TYPE:[A-Z]*=//p' "$POINTILLIST_BUILD/CMakeCache.txt")"
[[ "$build_type" == "Release" ]] ||
  say "warning: $POINTILLIST_BUILD is a '${build_type:-default}' build; the sweep runs slower and the measured traverse time is off"

if [[ -z "$dataset" ]]; then
  dataset="$POINTILLIST_ROOT/datasets/city-$points"
  ensure_city_dataset "$dataset" "$points"
fi

mkdir -p "$out"
out="$(cd "$out" && pwd)"
plots=(fps.png imbalance.png bytes.png)
args=(--dataset "$dataset" --camera-path "$camera" --frames "$frames" --size "$size"
  --renders "$renders" --traverses "$traverses" --datasends "$datasends" --scheduler "$schedulers"
  --jobs "$(nproc)" --csv "$out/simulate.csv" --report "$out/report.md")
[[ -z "$calibrate" ]] || args+=(--calibrate "$calibrate")
for p in "${plots[@]}"; do args+=(--report-plot "$p"); done

say "$(basename "$dataset"), $camera, $frames frames at $size; renders $renders, traverses $traverses, data-sends $datasends; $schedulers"
say "$(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg); progress below"
start=$SECONDS
if ! "$POINTILLIST_BIN/pointillist-simulate" "${args[@]}" "${sim_args[@]}" >"$out/table.txt"; then
  die "pointillist-simulate failed (message above); nothing was written to $out/simulate.csv"
fi
elapsed=$((SECONDS - start))

# One data file per (scheduler, traverse count): renders, frames/s, imbalance, MiB/frame.
data="$out/data"
rm -rf "$data"
mkdir -p "$data"
awk -F, -v dir="$data" '
  NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
  {
    name = $c["scheduler"]; gsub("/", "-", name)
    file = dir "/" name "-T" $c["traverses"] ".dat"
    printf "%s %s %s %s %s\n", $c["renders"], $c["frames_per_second_steady"], $c["imbalance_busy"],
      $c["bytes_per_frame_steady"] / 1048576, $c["datasends"] >> file
  }' "$out/simulate.csv"
mapfile -t series < <(awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
  !seen[$c["scheduler"]]++ { name = $c["scheduler"]; gsub("/", "-", name); print name }' "$out/simulate.csv")
IFS=, read -r -a traverse_list <<<"$traverses"
panels=${#traverse_list[@]}
columns=$((panels > 1 ? 2 : 1))
rows=$(((panels + columns - 1) / columns))
caption="$(basename "$dataset"), $camera, $frames frames at $size (simulated)"

plot() {  # FILE TITLE YLABEL COLUMN [EXTRA]
  {
    cat <<EOF
set terminal pngcairo size $((620 * columns)),$((430 * rows + 40)) font "sans,10" noenhanced
set output "$out/$1"
set multiplot layout $rows,$columns title "$2: $caption"
set logscale x 2
set xlabel "render processes"
set ylabel "$3"
set grid
set key top left box opaque
$5
EOF
    for t in "${traverse_list[@]}"; do
      echo "set title \"$t traverse process(es)\""
      printf 'plot'
      sep=""
      for i in "${!series[@]}"; do
        f="$data/${series[$i]}-T$t.dat"
        [[ -f "$f" ]] || continue
        printf '%s "%s" using 1:%d with linespoints lw 2 pt 7 ps 0.7 lc %d title "%s"' \
          "$sep" "$f" "$4" $((i + 1)) "${series[$i]}"
        sep=", \\"$'\n    '
      done
      echo
    done
    echo "unset multiplot"
  } | gnuplot
}
plot fps.png "Steady frames/s" "frames per second (steady, simulated)" 2 'set yrange [0:*]'
plot imbalance.png "Render imbalance" "max/mean busy time per frame (1 = balanced)" 3 'set logscale y'
plot bytes.png "Cell data per steady frame" "MiB sent to render processes per frame (log)" 4 'set logscale y'

cat "$out/table.txt"
echo
say "swept in ${elapsed} s; report: $out/report.md, figures: $out/simulate.csv, plots: ${plots[*]}"
