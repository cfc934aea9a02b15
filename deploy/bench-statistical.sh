#!/usr/bin/env bash
# Statistical point generation (seed 004) against plain points. For each scene
# it builds one dataset with --statistical (timing the preprocess and keeping
# its "statistical:" summary line), which serves both modes, then runs the same
# job twice -- --mode points and --mode statistical, GL renderer, PNG frames
# written -- and prints one table: bytes moved (first frame, steady per frame,
# total), frames/s, points drawn (points) or generated (statistical) per frame
# and per second per render process, and the statistical frames' PSNR and share
# of identical covered pixels against the points frames of the same cameras.
# It also runs pointillist-statistical-quality on each dataset (the
# rate-distortion curve; the depth closest to 2.5 bits per point is printed
# beside the paper's Lucy figure, 2.52 bits per point at 71 dB). Draws bytes,
# frames/s and the rate-distortion curves with gnuplot.
#
#   deploy/bench-statistical.sh [--scenes city,building,bunny] [--layout D,T,S,R]
#                               [--frames N] [--size WxH] [--path orbit] [--out DIR]
#                               [--max-generated N]
#                               [-- extra pointillist-preprocess options for --statistical]
#
# Scenes: city (built-in, 1 M points), building (CGAL's building.ply scan,
# 100 k points), bunny (the bunny mesh sampled to 2 M points). Defaults: layout
# 1,2,1,4, orbit, 48 frames at 1280x720, --max-generated 300000 (the quality
# tool's generated points per depth). Results go to OUT (out/bench-statistical):
# tables preprocess.md, table.md, rate-distortion.md; per scene the dataset,
# each run's frames, stats.json and CSVs (SCENE-points/, SCENE-statistical/),
# logs, SCENE-psnr.txt, SCENE-rd.md/.csv; plots bytes.png, fps.png, rd.png.
# The display encodes a PNG per frame, which costs both modes CPU: frames/s are
# lower than bench-instanced's (which writes none).
# Environment: POINTILLIST_BENCH_BUILD (default build-release, configured as Release).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/deploy/common.sh"
build="${POINTILLIST_BENCH_BUILD:-$root/build-release}"
out="$root/out/bench-statistical"
scenes=city,building,bunny
layout=1,2,1,4
frames=48
size=1280x720
path=orbit
max_generated=300000
extra=()
usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "${BASH_SOURCE[0]}"; }
die() { echo "bench-statistical: $*" >&2; exit 1; }
while (($#)); do
  case "$1" in
    --scenes|--layout|--frames|--size|--path|--out|--max-generated)
      (($# >= 2)) || die "$1 needs a value (see --help)"
      case "$1" in
        --scenes) scenes="$2" ;;
        --layout) layout="$2" ;;
        --frames) frames="$2" ;;
        --size) size="$2" ;;
        --path) path="$2" ;;
        --out) out="$2" ;;
        --max-generated) max_generated="$2" ;;
      esac
      shift 2 ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) usage; exit 0 ;;
    *) echo "bench-statistical: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ "$layout" =~ ^1,[1-9][0-9]*,[1-9][0-9]*,[1-9][0-9]*$ ]] ||
  die "--layout '$layout' is not 1,T,S,R (one display, at least one of each other role)"
[[ "$frames" =~ ^[1-9][0-9]*$ ]] || die "--frames '$frames' is not a positive count"
[[ "$size" =~ ^[1-9][0-9]*x[1-9][0-9]*$ ]] || die "--size '$size' is not WIDTHxHEIGHT"
[[ "$max_generated" =~ ^[1-9][0-9]*$ ]] || die "--max-generated '$max_generated' is not a positive count"
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
# The frame comparison needs numpy; a pyenv or venv python3 first on PATH may lack it.
python=""
for candidate in python3 /usr/bin/python3; do
  if command -v "$candidate" >/dev/null && "$candidate" -c 'import numpy' 2>/dev/null; then
    python="$candidate"
    break
  fi
done
[[ -n "$python" ]] || die "no python3 with numpy (Debian package python3-numpy)"
ensure_cgal_data
build_release "$build"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

input_of() { bench_scene_input "$1" || die "unknown scene '$1' (city, building, bunny)"; }
IFS=',' read -ra list <<<"$scenes"
((${#list[@]} > 0)) || die "--scenes needs at least one scene"
for scene in "${list[@]}"; do input_of "$scene" >/dev/null; done

# figure FILE NAME: one column of a run's figures.csv (a header line, a value line).
figure() {
  awk -F, -v name="$2" 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == name) c = i; next }
    NR == 2 && c { print $c }' "$1"
}
mib() { awk -v b="$1" 'BEGIN { printf "%.2f", b / 1048576 }'; }
mib3() { awk -v b="$1" 'BEGIN { printf "%.3f", b / 1048576 }'; }
mega() { awk -v n="$1" 'BEGIN { printf "%.2f M", n / 1e6 }'; }

prep="$out/preprocess.md"
table="$out/table.md"
rd="$out/rate-distortion.md"
plotdata="$out/plot.dat"
{
  echo "| scene | points | preprocess s (wall) | statistical.bin | nodes (leaves, depth) | bits/point position+normal | with colour and flags |"
  echo "|---|---:|---:|---:|---|---:|---:|"
} >"$prep"
{
  echo "| scene | mode | first frame MiB | steady MiB/frame | total MiB | frames/s steady | points drawn / generated per frame | M points/s per render process (steady; min-max) | PSNR dB vs points | identical covered pixels |"
  echo "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
} >"$table"
{
  echo "| scene | depth closest to 2.5 bits/point | cut nodes | bits/point position+normal | bits/point 18-byte nodes | generated (measured) | Hausdorff PSNR dB | paper, Lucy (14 M points) |"
  echo "|---|---:|---:|---:|---:|---:|---:|---|"
} >"$rd"
echo "# scene points_first statistical_first points_steady statistical_steady points_fps statistical_fps (MiB, frames/s)" >"$plotdata"
echo "bench-statistical: $scenes, layout $layout, $path, $frames frames at $size; $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)" >&2

for scene in "${list[@]}"; do
  read -ra input <<<"$(input_of "$scene")"
  dataset="$out/$scene"
  echo "bench-statistical: $scene: preprocessing with --statistical" >&2
  start=$(date +%s.%N)
  prep_out=$("$build/bin/pointillist-preprocess" "${input[@]}" -o "$dataset" --force --quiet \
    --statistical "${extra[@]}") || die "$scene: the preprocess failed"
  seconds=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }')
  echo "$prep_out" >"$out/$scene-preprocess.txt"
  summary=$(grep "statistical:" <<<"$prep_out") || die "$scene: the preprocess printed no 'statistical:' line"
  wrote=$(grep ": wrote " <<<"$prep_out" || true)
  point_count=$(sed -n 's/.*: wrote [^:]*: \([0-9]*\) points,.*/\1/p' <<<"$wrote")
  nodes=$(sed -n 's/.*statistical: \([0-9.]* *[kMG]*\) nodes (\([0-9.]* *[kMG]*\) leaves, [0-9.]* points per leaf, depth \([0-9]*\).*/\1 (\2, \3)/p' <<<"$summary")
  packet_bytes=$(sed -n 's/.*splits) in \(.*\) + classes .*/\1/p' <<<"$summary")
  bits=$(sed -n 's/.*: \([0-9.]*\) bits per point for position and normal.*/\1/p' <<<"$summary")
  bits_colour=$(sed -n 's/.*node), \([0-9.]*\) with colour and flags.*/\1/p' <<<"$summary")
  echo "| $scene | $(mega "${point_count:-0}") | $seconds | $packet_bytes | $nodes | $bits | $bits_colour |" >>"$prep"

  declare -A first=() steady=() fps=()
  for mode in points statistical; do
    run="$out/$scene-$mode"
    log="$out/$scene-$mode.log"
    rm -rf "$run"
    echo "bench-statistical: $scene: --mode $mode (log: $log)" >&2
    POINTILLIST_BUILD="$build" bash "$root/deploy/run.sh" --layout "$layout" --dataset "$dataset" \
      --mode "$mode" --renderer gl --camera-path "$path" --frames "$frames" --size "$size" \
      --out "$run" --quiet >"$log" 2>&1 || die "$scene --mode $mode failed (see $log)"
    figures="$run/figures.csv"
    [[ -s "$figures" ]] || die "$scene --mode $mode: the job wrote no $figures (see $log)"
    first[$mode]=$(mib "$(figure "$figures" bytes_first_frame)")
    steady[$mode]=$(mib3 "$(figure "$figures" bytes_per_frame_steady)")
    total=$(mib "$(figure "$figures" bytes_total)")
    fps[$mode]=$(awk -v f="$(figure "$figures" frames_per_second_steady)" 'BEGIN { printf "%.2f", f }')
    per_frame=$(mega "$(figure "$figures" splats_per_frame)")
    rate=$(awk -v m="$(figure "$figures" render_splats_per_second_mean)" \
      -v lo="$(figure "$figures" render_splats_per_second_min)" \
      -v hi="$(figure "$figures" render_splats_per_second_max)" \
      'BEGIN { printf "%.2f (%.2f-%.2f)", m / 1e6, lo / 1e6, hi / 1e6 }')
    psnr="reference" share="reference"
    if [[ "$mode" == statistical ]]; then
      "$python" "$root/deploy/frame_psnr.py" "$run" "$out/$scene-points" \
        --csv "$out/$scene-psnr.csv" >"$out/$scene-psnr.txt" ||
        die "$scene: comparing the frames failed (see $out/$scene-psnr.txt)"
      line=$(tail -1 "$out/$scene-psnr.txt")
      psnr=$(sed -n 's/.*mean PSNR \([0-9.a-z]*\) dB.*/\1/p' <<<"$line")
      share="$(sed -n 's/.*mean identical share \([0-9.]*\) %.*/\1/p' <<<"$line") %"
    fi
    echo "| $scene | $mode | ${first[$mode]} | ${steady[$mode]} | $total | ${fps[$mode]} | $per_frame | $rate | $psnr | $share |" >>"$table"
  done
  echo "$scene ${first[points]} ${first[statistical]} ${steady[points]} ${steady[statistical]} ${fps[points]} ${fps[statistical]}" >>"$plotdata"

  echo "bench-statistical: $scene: rate-distortion curve (--max-generated $max_generated)" >&2
  "$build/bin/pointillist-statistical-quality" "$dataset" --max-generated "$max_generated" \
    --csv "$out/$scene-rd.csv" >"$out/$scene-rd.md" || die "$scene: pointillist-statistical-quality failed"
  # The depth whose bits per point (position and normal) lie closest to 2.5.
  awk -F, -v scene="$scene" 'NR == 1 { next }
    { d = $4 - 2.5; if (d < 0) d = -d; if (best == "" || d < best) { best = d; row = $0 } }
    END { split(row, v, ","); printf "| %s | %d | %d | %.3f | %.3f | %d | %.2f | 2.52 bits/point at about 71 dB |\n",
          scene, v[1], v[2], v[4], v[5], v[6], v[7] }' "$out/$scene-rd.csv" >>"$rd"
done

# Bytes (first frame and steady) and frames/s per scene, both modes side by side.
histogram() {  # FILE TITLE YLABEL POINTS_COLUMN STATISTICAL_COLUMN
  gnuplot <<EOF
set terminal pngcairo size 1000,520 noenhanced
set output "$out/$1"
set title "Statistical (seed 004) against points: $2, $layout, $path, $size"
set style data histograms
set style histogram clustered gap 1
set style fill solid 0.8 border -1
set boxwidth 0.9
set key top left
set ylabel "$3"
set yrange [0:*]
set grid ytics
plot "$plotdata" using $4:xtic(1) title "points", "" using $5 title "statistical"
EOF
}
histogram bytes-first.png "first frame" "MiB sent to render processes, first frame" 2 3
histogram bytes.png "bytes per frame (steady)" "MiB sent to render processes per steady frame" 4 5
histogram fps.png "frames/s (steady)" "frames/s (steady)" 6 7

# Rate-distortion curves of every scene, with the paper's Lucy point.
{
  cat <<EOF
set terminal pngcairo size 1000,620 noenhanced
set output "$out/rd.png"
set title "Statistical hierarchies: rate against distortion, one point per cut depth"
set datafile separator ","
set xlabel "bits per point (position and normal, 13 bytes a node)"
set ylabel "Hausdorff PSNR (dB)"
set logscale x
set grid
set key bottom right box
EOF
  printf 'plot'
  sep=""
  for scene in "${list[@]}"; do
    printf '%s "%s" skip 1 using 4:7 with linespoints lw 2 pt 7 ps 0.7 title "%s"' "$sep" "$out/$scene-rd.csv" "$scene"
    sep=", \\"$'\n    '
  done
  printf '%s "-" using 1:2 with points pt 9 ps 2.5 lc rgb "black" title "Lucy, 14 M points (paper): 2.52 bits/point, 71 dB"\n' "$sep"
  echo "2.52,71"
  echo "e"
} | gnuplot

revision="$(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo unknown)"
if [[ "$revision" != unknown && -n "$(git -C "$root" status --porcelain --untracked-files=no 2>/dev/null)" ]]; then
  revision="$revision (with uncommitted changes)"
fi
{
  echo "# Statistical (seed 004) against points"
  echo
  echo "$(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, load at the end $(cut -d" " -f1-3 /proc/loadavg), $(basename "$build"), revision $revision"
  echo
  echo "## Preprocess (one --statistical dataset per scene, both modes)"
  echo
  cat "$prep"
  echo
  for scene in "${list[@]}"; do echo "- $scene: \`$(grep "statistical:" "$out/$scene-preprocess.txt")\`"; done
  echo
  echo "## Jobs ($layout, $path, $frames frames at $size, GL renderer, PNG frames written)"
  echo
  cat "$table"
  echo
  echo "Points drawn / generated and their rate are the render processes' counts (RenderStats.splats: in statistical mode the points the GL side generated). PSNR is over every pixel's RGB, the mean over the frames that differ; the identical share counts pixels off the background in either frame, mean over frames."
  echo
  echo "## Rate-distortion (pointillist-statistical-quality --max-generated $max_generated)"
  echo
  cat "$rd"
} >"$out/report.md"
cat "$out/report.md"
echo
echo "bench-statistical: report in $out/report.md (tables preprocess.md, table.md, rate-distortion.md; curves SCENE-rd.md); plots bytes-first.png, bytes.png, fps.png, rd.png in $out" >&2
