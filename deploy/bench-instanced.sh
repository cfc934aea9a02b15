#!/usr/bin/env bash
# Instanced point generation (seed 000) against plain points. For each scene it
# builds a plain and an --instanced dataset (timing both preprocesses and
# keeping the instancing summary: coverage, bytes in the paper's accounting,
# colour error, FFT time), then runs the same job three ways -- points on the
# plain dataset, points on the instanced one, instanced -- and prints one
# table: bytes moved (first frame, steady per frame, total), frames/s and
# points drawn per frame. Draws the bytes and frames/s with gnuplot.
#
#   deploy/bench-instanced.sh [--scenes city,building,bunny] [--layout D,T,S,R]
#                             [--frames N] [--size WxH] [--path orbit] [--out DIR]
#                             [-- extra pointillist-preprocess options for --instanced]
#
# Scenes: city (built-in, 1 M points), building (CGAL's building.ply scan,
# 100 k points), bunny (the bunny mesh sampled to 2 M points).
# Environment: POINTILLIST_BENCH_BUILD (default build-release, configured as Release).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/deploy/common.sh"
build="${POINTILLIST_BENCH_BUILD:-$root/build-release}"
out="$root/out/bench-instanced"
scenes=city,building,bunny
layout=1,2,1,4
frames=48
size=1280x720
path=orbit
extra=()
while (($#)); do
  case "$1" in
    --scenes) scenes="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --path) path="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,17p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench-instanced: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
die() { echo "bench-instanced: $*" >&2; exit 1; }
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
ensure_cgal_data
build_release "$build"
mkdir -p "$out"

input_of() { bench_scene_input "$1" || die "unknown scene '$1' (city, building, bunny)"; }

# seconds_of LINE: the seconds of a preprocess summary line ("... in S s (...").
seconds_of() { sed -n 's/.* in \([0-9.]*\) s (.*/\1/p' <<<"$1" | head -1; }

table="$out/table.md"
prep="$out/preprocess.md"
plotdata="$out/plot.dat"
{
  echo "| scene | plain preprocess s | --instanced preprocess s | covered | sections vs plain | vertex / translation / tag bytes | colour error mean / max | FFT s (ms per unit) |"
  echo "|---|---:|---:|---:|---:|---|---|---|"
} >"$prep"
{
  echo "| scene | run | first frame MiB | steady MiB/frame | total MiB | frames/s steady | points drawn per frame |"
  echo "|---|---|---:|---:|---:|---:|---:|"
} >"$table"
: >"$plotdata"
IFS=',' read -ra list <<<"$scenes"
for scene in "${list[@]}"; do
  read -ra input <<<"$(input_of "$scene")"
  plain="$out/$scene-plain" inst="$out/$scene-instanced"
  echo "bench-instanced: $scene: preprocessing" >&2
  plain_line=$("$build/bin/pointillist-preprocess" "${input[@]}" -o "$plain" --force --quiet | tail -1)
  inst_out=$("$build/bin/pointillist-preprocess" "${input[@]}" -o "$inst" --force --quiet --instanced "${extra[@]}")
  inst_line=$(grep "wrote" <<<"$inst_out")
  summary=$(grep "instanced:" <<<"$inst_out")
  echo "$summary" >"$out/$scene-instancing.txt"
  covered=$(sed -n 's/.*instanced: \([0-9.]* %\).*/\1/p' <<<"$summary")
  ratio=$(sed -n 's/.*sections \(.*\) as plain splats (\([0-9.]*x\) smaller).*/\1 (\2)/p' <<<"$summary")
  parts=$(sed -n 's/.*-- vertices \(.*\), translations \(.*\), tags \([^;]*\);.*/\1 \/ \2 \/ \3/p' <<<"$summary")
  colour=$(sed -n 's/.*mean \([0-9.]*\), max \([0-9]*\) of 255.*/\1 \/ \2/p' <<<"$summary")
  fft=$(sed -n 's/.*FFT \([0-9.]*\) s (\([0-9.]*\) ms per unit.*/\1 (\2)/p' <<<"$summary")
  echo "| $scene | $(seconds_of "$plain_line") | $(seconds_of "$inst_line") | $covered | $ratio | $parts | $colour | $fft |" >>"$prep"

  for run in points-plain points-instanced instanced; do
    case "$run" in
      points-plain) dataset="$plain" mode=points ;;
      points-instanced) dataset="$inst" mode=points ;;
      instanced) dataset="$inst" mode=instanced ;;
    esac
    echo "bench-instanced: $scene: $run" >&2
    log="$out/$scene-$run.log"
    POINTILLIST_BUILD="$build" bash "$root/deploy/run.sh" --layout "$layout" --dataset "$dataset" \
      --mode "$mode" --renderer gl --camera-path "$path" --frames "$frames" --size "$size" \
      --quiet >"$log" 2>&1 || die "$scene $run failed (see $log)"
    bytes=$(grep '^bytes sent:' "$log")
    total=$(sed -n 's/bytes sent: \([0-9.]*\) MiB total.*/\1/p' <<<"$bytes")
    first=$(sed -n 's/.*first frame \([0-9.]*\) MiB.*/\1/p' <<<"$bytes")
    steady=$(sed -n 's/.*, \([0-9.]*\) MiB per frame steady.*/\1/p' <<<"$bytes")
    fps=$(sed -n 's/.*, \([0-9.]*\) frames\/s steady.*/\1/p' "$log")
    drawn=$(sed -n 's/^splats: \([0-9.]* [kM]*\) per frame.*/\1/p' "$log")
    echo "| $scene | $run | $first | $steady | $total | $fps | $drawn |" >>"$table"
    echo "\"$scene $run\" $first $steady $fps" >>"$plotdata"
  done
done

# Bytes (first frame and steady) and frames/s per scene and run.
for what in first steady fps; do
  case "$what" in
    first) column=2 label="first frame (MiB)" ;;
    steady) column=3 label="steady (MiB per frame)" ;;
    fps) column=4 label="frames/s (steady)" ;;
  esac
  gnuplot <<EOF
set terminal pngcairo size 1000,480
set output "$out/$what.png"
set title "Instanced (seed 000) against points: $label, $layout, $path, $size"
set style data histograms
set style fill solid 0.8
set boxwidth 0.8
set xtics rotate by -30
set ylabel "$label"
set grid ytics
plot "$plotdata" using $column:xtic(1) notitle
EOF
done
cat "$prep"
echo
cat "$table"
echo
echo "bench-instanced: tables in $prep and $table; plots first.png, steady.png, fps.png in $out"
