#!/usr/bin/env bash
# Preprocess throughput benchmark. Makes the inputs users bring (once, cached
# in OUT/inputs) with pointillist-make-points from the Stanford bunny of
# libcgal-demo, runs pointillist-preprocess from a Release build on each and
# prints one table: wall time, points/s, points/s per core, CPU, peak memory,
# and the time of each stage. Plots (gnuplot): stages.png, each input's time
# stacked by stage; rate.png, points/s per core against the goal of 2 M.
#
#   deploy/bench-preprocess.sh [--points N] [--inputs ply,xyz,mesh,xyz-knn,big] [--out DIR]
#                              [--big-points N] [--memory-mb MB] [--repeat N]
#                              [-- extra pointillist-preprocess options]
#
# --repeat N runs every input N times, the inputs in turn (this VM's speed
# drifts by half within minutes): the table gives the median run's figures
# and the range of wall times; the plots show the median run.
#
# Inputs (N points each, default 10 M):
#   ply   binary PLY with normals and colours, no radii (a sampled mesh)
#   xyz   XYZ text "x y z r g b", no normals (what a scanner exports); from
#         2 M points normals come from cube moments (--normals auto)
#   xyz-knn  the same file with --normals knn, each point's 12 nearest
#         neighbours (not by default)
#   mesh  the bunny mesh itself, sampled by the preprocessor (reading is cheap)
#   big   the ply kind with --big-points points (default 200 M, 5.4 GB), built
#         out of core under --memory-mb (default 4096); needs about 25 GB of
#         disk for the input, the spill files and the dataset (not by default)
# Environment: POINTILLIST_BENCH_BUILD (default build-release, configured as Release).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${POINTILLIST_BENCH_BUILD:-$root/build-release}"
out="$root/out/bench-preprocess"
points=10000000
inputs=ply,xyz,mesh
big_points=200000000
memory_mb=4096
repeat=1
extra=()
while (($#)); do
  case "$1" in
    --points) points="$2"; shift 2 ;;
    --inputs) inputs="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --big-points) big_points="$2"; shift 2 ;;
    --memory-mb) memory_mb="$2"; shift 2 ;;
    --repeat) repeat="$2"; shift 2 ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,24p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench-preprocess: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done

[[ "$repeat" =~ ^[1-9][0-9]*$ ]] || { echo "bench-preprocess: --repeat wants a whole number >= 1, got '$repeat'" >&2; exit 2; }
command -v gnuplot >/dev/null || {
  echo "bench-preprocess: gnuplot is missing (Debian package gnuplot-nox)" >&2
  exit 1
}
mesh="$root/.cache/cgal-data/data/meshes/bunny00.off"
[[ -f "$mesh" ]] || bash "$root/deploy/fetch-test-data.sh"
[[ -f "$mesh" ]] || { echo "bench-preprocess: no mesh at $mesh" >&2; exit 1; }
if [[ ! -f "$build/CMakeCache.txt" ]]; then
  echo "bench-preprocess: configuring a Release build in $build" >&2
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
build_type="$(sed -n 's/^CMAKE_BUILD_TYPE:[A-Z]*=//p' "$build/CMakeCache.txt")"
[[ "$build_type" == "Release" ]] || echo "bench-preprocess: warning: $build is a '$build_type' build" >&2
cmake --build "$build" --target pointillist-preprocess pointillist-make-points -j "$(nproc)" >/dev/null

mkdir -p "$out/inputs"
cores=$(nproc)
table="$out/table.md"
{
  echo "| input | points | wall s | points/s | points/s per core | CPU s | peak MiB | stages (s) |"
  echo "|---|---:|---:|---:|---:|---:|---:|---|"
} >"$table"
stages_tsv="$out/stages.tsv"  # input, stage, seconds (the median run)
rates_tsv="$out/rates.tsv"    # input, points/s per core (M, the median run)
runs_tsv="$out/runs.tsv"      # input, run, wall s, peak KiB, user s, sys s
: >"$stages_tsv"
: >"$rates_tsv"
: >"$runs_tsv"
IFS=',' read -ra kinds <<<"$inputs"
declare -A input_of points_of
for kind in "${kinds[@]}"; do
  n="$points"
  case "$kind" in
    big) n="$big_points"; input="$out/inputs/bunny-$n.ply"; args=(--mesh "$mesh" --points "$n" --format ply) ;;
    ply) input="$out/inputs/bunny-$points.ply"; args=(--mesh "$mesh" --points "$points" --format ply) ;;
    xyz|xyz-knn) input="$out/inputs/bunny-$points.xyz"; args=(--mesh "$mesh" --points "$points" --format xyz --no-normals) ;;
    mesh) input="$mesh"; args=() ;;
    *) echo "bench-preprocess: unknown input '$kind' (ply, xyz, mesh, xyz-knn, big)" >&2; exit 2 ;;
  esac
  if [[ "$kind" != mesh && ! -f "$input" ]]; then
    "$build/bin/pointillist-make-points" "${args[@]}" -o "$input"
  fi
  input_of[$kind]="$input"
  points_of[$kind]="$n"
done
for ((run = 1; run <= repeat; ++run)); do
  for kind in "${kinds[@]}"; do
    input="${input_of[$kind]}"
    dataset="$out/dataset-$kind"
    log="$out/$kind.$run.log"
    cmd=("$build/bin/pointillist-preprocess" "$input" -o "$dataset" --force)
    [[ "$kind" == mesh ]] && cmd+=(--points "$points")
    [[ "$kind" == big ]] && cmd+=(--memory-mb "$memory_mb")
    [[ "$kind" == xyz-knn ]] && cmd+=(--normals knn)
    echo "bench-preprocess: $kind, run $run of $repeat: ${cmd[*]} ${extra[*]}" >&2
    # Cold page cache would measure the disk, not us: read the input once first.
    cat "$input" >/dev/null
    # A new dataset, as a first run makes: replacing the last run's (--force)
    # would time freeing its blocks too (0.3-0.4 s for 430 MB on this VM's ext4).
    rm -rf "$dataset"
    /usr/bin/time -f '%e %M %U %S' -o "$log.time" "${cmd[@]}" "${extra[@]}" 2>"$log" >>"$log"
    read -r wall rss_kib user sys <"$log.time"
    printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$kind" "$run" "$wall" "$rss_kib" "$user" "$sys" >>"$runs_tsv"
    rm -f "$log.time"
  done
done
for kind in "${kinds[@]}"; do
  n="${points_of[$kind]}"
  # The median run by wall time (the lower middle one for an even count).
  read -r run wall rss_kib user sys low high < <(awk -F'\t' -v k="$kind" '$1 == k { w[++n] = $3; line[n] = $2 " " $3 " " $4 " " $5 " " $6 }
    END {
      for (i = 1; i <= n; ++i) for (j = i + 1; j <= n; ++j) if (w[j] < w[i]) { t = w[i]; w[i] = w[j]; w[j] = t; t = line[i]; line[i] = line[j]; line[j] = t }
      print line[int((n + 1) / 2)], w[1], w[n]
    }' "$runs_tsv")
  log="$out/$kind.$run.log"
  cp "$log" "$out/$kind.log"
  stages=$(sed -n 's/^  \(.*\): done in \([0-9.]*\) s$/\1 \2/p' "$log" | awk '{ t = $NF; $NF = ""; sub(/ $/, ""); printf "%s%s %s", sep, $0, t; sep = ", " }')
  sed -n 's/^  \(.*\): done in \([0-9.]*\) s$/\1\t\2/p' "$log" | sed "s/^/$kind\t/" >>"$stages_tsv"
  awk -v k="$kind" -v p="$n" -v w="$wall" -v c="$cores" 'BEGIN { printf "%s\t%.3f\n", k, p / w / c / 1e6 }' >>"$rates_tsv"
  label="$kind"
  [[ "$kind" == big ]] && label="big (--memory-mb $memory_mb)"
  awk -v k="$label" -v p="$n" -v w="$wall" -v lo="$low" -v hi="$high" -v reps="$repeat" -v r="$rss_kib" -v u="$user" -v s="$sys" -v c="$cores" -v st="$stages" 'BEGIN {
    spread = reps > 1 ? sprintf(" (%.2f-%.2f)", lo, hi) : ""
    printf "| %s | %.1f M | %.2f%s | %.2f M | %.2f M | %.2f | %.0f | %s |\n", k, p / 1e6, w, spread, p / w / 1e6, p / w / c / 1e6, u + s, r / 1024, st }' >>"$table"
done

# Stages as columns (in the order they first appear), inputs as rows.
stages_dat="$out/stages.dat"
awk -F'\t' '
  !($2 in column) { column[$2] = ++columns; name[columns] = $2 }
  !($1 in row) { row[$1] = ++rows; input[rows] = $1 }
  { time[row[$1], column[$2]] = $3 }
  END {
    printf "input"
    for (c = 1; c <= columns; ++c) printf "\t%s", name[c]
    printf "\n"
    for (r = 1; r <= rows; ++r) {
      printf "%s", input[r]
      for (c = 1; c <= columns; ++c) printf "\t%s", ((r, c) in time) ? time[r, c] : 0
      printf "\n"
    }
  }' "$stages_tsv" >"$stages_dat"
stage_columns=$(head -1 "$stages_dat" | awk -F'\t' '{ print NF }')
gnuplot <<GNUPLOT
set terminal pngcairo size 1000,560 noenhanced
set output "$out/stages.png"
set title "pointillist-preprocess, $cores cores: time by stage"
set datafile separator "\t"
set style data histograms
set style histogram rowstacked
set style fill solid 0.85 border -1
set boxwidth 0.6
set key outside right top
set ylabel "seconds"
set yrange [0:*]
set grid ytics
plot for [c=2:$stage_columns] "$stages_dat" using c:xtic(1) title columnheader(c)
GNUPLOT
gnuplot <<GNUPLOT
set terminal pngcairo size 800,480 noenhanced
set output "$out/rate.png"
set title "pointillist-preprocess: points/s per core, reading to writing ($cores cores)"
set datafile separator "\t"
set style data histograms
set style fill solid 0.85 border -1
set boxwidth 0.6
set ylabel "M points/s per core"
set yrange [0:2.5<*]
set grid ytics
set key top right
plot "$rates_tsv" using 2:xtic(1) title "measured", 2.0 with lines lw 2 dt 2 lc rgb "black" title "goal (2 M)"
GNUPLOT

echo
runs_note=""
((repeat > 1)) && runs_note="; median of $repeat runs each, the inputs in turn, wall range in brackets (runs.tsv has every run)"
echo "pointillist-preprocess, $cores cores ($build_type build)$runs_note; logs, datasets and plots (stages.png, rate.png) in $out"
cat "$table"
