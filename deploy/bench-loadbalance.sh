#!/usr/bin/env bash
# Load-balance benchmark: runs the same job once per scheduler and compares
# frame rate, splats/s per render process, imbalance, bytes sent per frame and
# cache hit rate; draws the plots with gnuplot.
#
#   deploy/bench-loadbalance.sh --dataset D [--layout 1,2,1,4] [--camera-path orbit]
#       [--frames 48] [--size 1280x720] [--scheduler S[,S...]] [--out DIR]
#       [--points N] [--repeat N] [--variant LABEL=SCHEDULER[:OPTIONS]]...
#       [--save-frames] [-- more job options, e.g. --cache-mb 256]
#
# --repeat N runs every entry N times, interleaved (entry by entry, then again)
# so that drift in the machine's load spreads over all of them; the table shows
# the median run and the range of steady frames/s. --variant adds a row that
# runs SCHEDULER with extra job options, e.g. the cost scheduler as the paper
# writes it: --variant "cost-paper=cost:--cost-model paper --prefetch-frames 0 --equal-tiles"
#
# --dataset city generates the built-in scene with --points N points (default
# 2000000) into datasets/city-N unless it is there already. Schedulers default
# to cost,regions,round-robin,static,equalizer (the job option --scheduler NAME).
# Each run goes to OUT/<scheduler>/ (stats.json, *.csv, run.log, and the PNG
# frames with --save-frames: off by default, because the display's PNG encoding
# competes with the render processes for the CPU and would dominate the figures);
# OUT/report.md, OUT/summary.csv and OUT/*.png compare them:
#   workload-<scheduler>.png  queued splats per render process over time
#   frame-time.png            seconds from first tile handed out to frame composed
#   bytes-per-frame.png       cell data sent to render processes per frame
#   imbalance.png             max/mean busy time and splats per frame
# Environment: POINTILLIST_BUILD (default build-release), POINTILLIST_BUILD_TYPE
# (default Release; used when the build directory is configured).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export POINTILLIST_BUILD="${POINTILLIST_BUILD:-$root/build-release}"
export POINTILLIST_BUILD_TYPE="${POINTILLIST_BUILD_TYPE:-Release}"
source "$root/deploy/common.sh"

me="bench-loadbalance"
die() { printf '%s: %s\n' "$me" "$*" >&2; exit 2; }
say() { printf '%s: %s\n' "$me" "$*" >&2; }
usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "${BASH_SOURCE[0]}"; }

dataset=""
layout="1,2,1,4"
camera="orbit"
frames=48
size="1280x720"
schedulers="cost,regions,round-robin,static,equalizer"
out="out/bench-loadbalance"
points=""
save_frames=0
repeat=1
job_args=()
declare -A variant_scheduler=() variant_options=()
variant_labels=()
while (($#)); do
  case "$1" in
    --dataset|--layout|--camera-path|--frames|--size|--scheduler|--out|--points|--repeat|--variant)
      (($# >= 2)) || die "$1 needs a value (see --help)"
      case "$1" in
        --dataset) dataset="$2" ;;
        --layout) layout="$2" ;;
        --camera-path) camera="$2" ;;
        --frames) frames="$2" ;;
        --size) size="$2" ;;
        --scheduler) schedulers="$2" ;;
        --out) out="$2" ;;
        --points) points="$2" ;;
        --repeat) repeat="$2" ;;
        --variant)
          [[ "$2" =~ ^([a-z0-9][a-z0-9_-]*)=([a-z0-9-]+)(:(.*))?$ ]] ||
            die "--variant '$2' is not LABEL=SCHEDULER[:JOB OPTIONS] (e.g. cost-paper=cost:--cost-model paper)"
          [[ -z "${variant_scheduler[${BASH_REMATCH[1]}]:-}" ]] || die "variant '${BASH_REMATCH[1]}' is given twice"
          variant_labels+=("${BASH_REMATCH[1]}")
          variant_scheduler[${BASH_REMATCH[1]}]="${BASH_REMATCH[2]}"
          variant_options[${BASH_REMATCH[1]}]="${BASH_REMATCH[4]}" ;;
      esac
      shift 2 ;;
    --save-frames) save_frames=1; shift ;;
    --) shift; job_args+=("$@"); break ;;
    -h|--help) usage; exit 0 ;;
    *) die "unknown option '$1' (job options go after --; see --help)" ;;
  esac
done

[[ -n "$dataset" ]] || die "--dataset is required (a preprocessed dataset directory, or 'city')"
[[ "$layout" =~ ^1,[1-9][0-9]*,[1-9][0-9]*,[1-9][0-9]*$ ]] ||
  die "--layout '$layout' is not 1,T,S,R (one display, at least one of each other role)"
[[ "$frames" =~ ^[1-9][0-9]*$ ]] || die "--frames '$frames' is not a positive count"
[[ "$repeat" =~ ^[1-9][0-9]*$ ]] || die "--repeat '$repeat' is not a positive count"
[[ "$size" =~ ^[1-9][0-9]*x[1-9][0-9]*$ ]] || die "--size '$size' is not WIDTHxHEIGHT"
if [[ -n "$points" && "$dataset" != "city" ]]; then
  die "--points only applies to --dataset city (the generated scene)"
fi
[[ -z "$points" || "$points" =~ ^[1-9][0-9]*$ ]] || die "--points '$points' is not a positive count"
IFS=, read -r -a scheduler_list <<<"$schedulers"
((${#scheduler_list[@]} > 0)) || die "--scheduler needs at least one name"
declare -A seen=()
for s in "${scheduler_list[@]}"; do
  [[ "$s" =~ ^[a-z0-9][a-z0-9_-]*$ ]] || die "scheduler name '$s' is not a lower-case name (list them as cost,static,...)"
  [[ -z "${seen[$s]:-}" ]] || die "scheduler '$s' is listed twice"
  seen[$s]=1
  variant_scheduler[$s]="$s"
  variant_options[$s]=""
done
for label in "${variant_labels[@]}"; do
  [[ -z "${seen[$label]:-}" ]] || die "variant '$label' has the name of a listed scheduler"
  seen[$label]=1
  scheduler_list+=("$label")
done

check_dataset() {
  [[ -f "$dataset/manifest.txt" ]] ||
    die "dataset '$dataset' is not a preprocessed dataset (no manifest.txt; make one with pointillist-preprocess)"
}
[[ "$dataset" == "city" ]] || check_dataset

install_packages
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
if [[ ! -f "$POINTILLIST_BUILD/CMakeCache.txt" ]]; then
  log "configuring a $POINTILLIST_BUILD_TYPE build in $POINTILLIST_BUILD"
  cmake -S "$POINTILLIST_ROOT" -B "$POINTILLIST_BUILD" -DCMAKE_BUILD_TYPE="$POINTILLIST_BUILD_TYPE" \
    -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
build_all
build_type="$(sed -n 's/^CMAKE_BUILD_TYPE:[A-Z]*=//p' "$POINTILLIST_BUILD/CMakeCache.txt")"
[[ "$build_type" == "Release" ]] ||
  say "warning: $POINTILLIST_BUILD is a '${build_type:-default}' build; Release figures are the ones to compare"

if [[ "$dataset" == "city" ]]; then
  points="${points:-2000000}"
  dataset="$POINTILLIST_ROOT/datasets/city-$points"
  ensure_city_dataset "$dataset" "$points"
fi
check_dataset

# Older builds have no --scheduler option, and every role ignores options it
# does not know, so a scheduler name would be silently ignored: only the
# built-in cost choice is then available. Newer builds reject unknown names.
# A job needs every role even to print help; rank 0 (the display) prints it.
help_job=(mpirun --mca btl_vader_single_copy_mechanism none --oversubscribe --bind-to none
  -np 1 "$POINTILLIST_BIN/pointillist-display" --help)
for exe in traverse datasend render; do
  help_job+=(: -np 1 "$POINTILLIST_BIN/pointillist-$exe" --help)
done
display_help="$("${help_job[@]}" 2>&1 || true)"
if grep -q -- '--scheduler' <<<"$display_help"; then
  scheduler_option=1
else
  scheduler_option=0
  for s in "${scheduler_list[@]}"; do
    [[ "$s" == "cost" ]] ||
      die "scheduler '$s': $POINTILLIST_BIN/pointillist-display has no --scheduler option, so only 'cost' (the built-in choice) can run; rebuild with scheduler support"
  done
  say "note: this build has no --scheduler option; 'cost' runs the built-in choice"
fi

mkdir -p "$out"
out="$(cd "$out" && pwd)"
job_options() {  # ENTRY -> the role options of a run
  local options=(--dataset "$dataset" --camera-path "$camera") extra=()
  ((scheduler_option)) && options+=(--scheduler "${variant_scheduler[$1]}")
  read -r -a extra <<<"${variant_options[$1]}"
  printf '%s\0' "${options[@]}" "${extra[@]}" "${job_args[@]}"
}
run_job() {  # SCHEDULER FRAMES SIZE DIR LOG
  local options=()
  mapfile -d '' options < <(job_options "$1")
  if ((save_frames)); then options+=(--out "$4"); else options+=(--stats "$4/stats.json"); fi
  bash "$POINTILLIST_ROOT/deploy/run.sh" --layout "$layout" "${options[@]}" --frames "$2" \
    --size "$3" >"$5" 2>&1
}
show_failure() {  # SCHEDULER LOG
  say "scheduler '$1' failed; last lines of $2:"
  # Without the frame lines and Open MPI's abort banner (between dashed lines).
  awk '/^--------------------/ { banner = !banner; next } !banner && !/^frame /' "$2" | tail -n 12 | sed 's/^/    /' >&2
}

# A one-frame probe per scheduler first, so that an unknown name or a bad job
# option stops the benchmark before any long run.
if ((scheduler_option)); then
  for s in "${scheduler_list[@]}"; do
    probe="$out/.probe-$s"
    rm -rf "$probe"
    mkdir -p "$probe"
    if ! run_job "$s" 1 160x90 "$probe" "$probe/run.log"; then
      show_failure "$s" "$probe/run.log"
      die "scheduler '$s' does not run (an unknown scheduler, or see the log above); nothing was measured"
    fi
    rm -rf "$probe"
  done
fi

say "$dataset, layout $layout, $camera, $frames frames at $size, schedulers: ${scheduler_list[*]}"
say "$(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg), $build_type build"
declare -A load=() failed_set=()
failed=()
done_list=()
runs_csv="$out/runs.csv"
rm -f "$runs_csv"
total=$((${#scheduler_list[@]} * repeat))
index=0
for ((run = 1; run <= repeat; ++run)); do
  for s in "${scheduler_list[@]}"; do
    index=$((index + 1))
    [[ -z "${failed_set[$s]:-}" ]] || continue
    dir="$out/$s/run-$run"
    ((repeat > 1)) || dir="$out/$s"
    ((run > 1)) || rm -rf "$out/$s"
    mkdir -p "$dir"
    say "[$index/$total] $s${variant_options[$s]:+ (${variant_options[$s]})}, run $run of $repeat: running (log: $dir/run.log)"
    load[$s]="${load[$s]:-}${load[$s]:+ }$(cut -d' ' -f1 /proc/loadavg)"
    start=$SECONDS
    if ! run_job "$s" "$frames" "$size" "$dir" "$dir/run.log"; then
      show_failure "$s" "$dir/run.log"
      failed+=("$s")
      failed_set[$s]=1
      continue
    fi
    for f in frames.csv renders.csv per_frame_render.csv figures.csv; do
      if [[ ! -s "$dir/$f" ]]; then
        say "scheduler '$s': the job ran but wrote no $dir/$f (a display without CSV output?)"
        failed+=("$s")
        failed_set[$s]=1
        continue 2
      fi
    done
    [[ -s "$runs_csv" ]] || { printf 'scheduler,run,'; head -n 1 "$dir/figures.csv"; } >"$runs_csv"
    { printf '%s,%d,' "$s" "$run"; sed -n 2p "$dir/figures.csv"; } >>"$runs_csv"
    awk -F, -v s="$s" -v t=$((SECONDS - start)) 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
      { printf "bench-loadbalance: %s: %.2f frames/s steady, imbalance busy %.2f, hit rate %.1f%% steady (%d s)\n",
          s, $c["frames_per_second_steady"], $c["imbalance_busy"], 100 * $c["cache_hit_rate_steady"], t }' \
      "$dir/figures.csv" >&2
  done
done
for s in "${scheduler_list[@]}"; do
  [[ -n "${failed_set[$s]:-}" ]] || done_list+=("$s")
done
if ((repeat > 1)); then
  # The median run by steady frames/s stands for its entry (table and plots).
  for s in "${done_list[@]}"; do
    median_run="$(awk -F, -v s="$s" 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
      $1 == s { print $c["frames_per_second_steady"], $2 }' "$runs_csv" | sort -g | awk '{ r[NR] = $2 } END { print r[int((NR + 1) / 2)] }')"
    for f in "$out/$s/run-$median_run"/*; do cp "$f" "$out/$s/"; done
    echo "$median_run" >"$out/$s/median-run.txt"
  done
fi
((${#done_list[@]} > 0)) || die "no scheduler ran to the end: ${failed[*]}"

# summary.csv: the scheduler, then every column of the runs' figures.csv.
{
  printf 'scheduler,'
  head -n 1 "$out/${done_list[0]}/figures.csv"
  for s in "${done_list[@]}"; do
    printf '%s,' "$s"
    sed -n 2p "$out/$s/figures.csv"
  done
} >"$out/summary.csv"

# The comparison table, in markdown; the same text is printed at the end.
table="$(awk -F, -v ranges="$(
  if ((repeat > 1)); then awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
    { f = $c["frames_per_second_steady"]; s = $1
      if (!(s in lo) || f < lo[s]) lo[s] = f
      if (!(s in hi) || f > hi[s]) hi[s] = f }
    END { for (s in lo) printf "%s=%.2f-%.2f;", s, lo[s], hi[s] }' "$runs_csv"; fi)" '
  BEGIN { n = split(ranges, parts, ";"); for (i = 1; i <= n; ++i) if (split(parts[i], kv, "=") == 2) range[kv[1]] = kv[2] }
  NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
  function v(name) { return $c[name] }
  function mib(bytes) { return sprintf("%.3f", bytes / 1048576) }
  {
    n = ++rows
    cell[n, 1] = v("scheduler")
    cell[n, 2] = sprintf("%.2f", v("frames_per_second"))
    cell[n, 3] = sprintf("%.2f", v("frames_per_second_steady"))
    cell[n, 4] = sprintf("%.2f (%.2f-%.2f)", v("render_splats_per_second_mean") / 1e6,
                         v("render_splats_per_second_min") / 1e6, v("render_splats_per_second_max") / 1e6)
    cell[n, 5] = sprintf("%.2f", v("imbalance_busy"))
    cell[n, 6] = sprintf("%.2f", v("imbalance_splats"))
    cell[n, 7] = mib(v("bytes_first_frame"))
    cell[n, 8] = mib(v("bytes_per_frame_steady"))
    cell[n, 9] = sprintf("%.1f%% (%.1f%%)", 100 * v("cache_hit_rate_steady"), 100 * v("cache_hit_rate"))
    cell[n, 10] = sprintf("%d", v("reissued_tiles"))
    cell[n, 11] = sprintf("%.2f", v("imbalance_busy_run"))
    if (range[v("scheduler")] != "") cell[n, 3] = cell[n, 3] " (" range[v("scheduler")] ")"
  }
  END {
    split("scheduler|frames/s overall|frames/s steady|M splats/s per render: mean (min-max)|imbalance busy|imbalance splats|MiB/frame first|MiB/frame steady|cache hits steady (all)|re-issued tiles|imbalance busy (run)", head, "|")
    for (j = 1; j <= 11; ++j) { cell[0, j] = head[j]; w[j] = length(head[j]) }
    for (i = 1; i <= rows; ++i) for (j = 1; j <= 11; ++j) if (length(cell[i, j]) > w[j]) w[j] = length(cell[i, j])
    for (i = 0; i <= rows; ++i) {
      line = "|"
      for (j = 1; j <= 11; ++j) line = line sprintf(j == 1 ? " %-*s |" : " %*s |", w[j], cell[i, j])
      print line
      if (i == 0) {
        line = "|"
        for (j = 1; j <= 11; ++j) { dashes = sprintf("%*s", w[j], ""); gsub(/ /, "-", dashes); line = line (j == 1 ? "-" dashes "-|" : "-" dashes ":|") }
        print line
      }
    }
  }' "$out/summary.csv")"

# Plots. Lines of the same scheduler keep their colour across the plots.
plot_setup() {  # FILE TITLE
  cat <<EOF
set terminal pngcairo size 1100,620 font "sans,11" noenhanced
set output "$1"
set title "$2"
set datafile separator ","
set key outside right top box
set grid
EOF
}
runs_caption="$(basename "$dataset"), layout $layout, $camera, $size"
plot_files=()
rm -f "$out"/workload-*.png  # from earlier runs with other schedulers
for s in "${done_list[@]}"; do
  # Split renders.csv into one block per render rank (t, queued Msplats).
  awk -F, 'NR > 1 { if ($3 != rank) { if (NR > 2) printf "\n\n"; rank = $3; print "# rank " rank }
                    print $1 "," $4 / 1e6 }' "$out/$s/renders.csv" >"$out/$s/workload.dat"
  mapfile -t ranks < <(awk -F, 'NR > 1 && !seen[$3]++ { print $3 }' "$out/$s/renders.csv")
  frame_ends="$(awk -F, 'NR > 1 { printf "%s%s", sep, $3; sep = " " }' "$out/$s/frames.csv")"
  {
    plot_setup "$out/workload-$s.png" "Workload per render process over time: $s ($runs_caption)"
    echo 'set xlabel "time since the run began (s); grey lines: a frame is composed"'
    echo 'set ylabel "queued splats (millions)"'
    echo 'set yrange [0:*]'
    for t in $frame_ends; do echo "set arrow from first $t, graph 0 to first $t, graph 1 nohead lc rgb '#d0d0d0' lw 1 back"; done
    printf 'plot'
    sep=""
    for i in "${!ranks[@]}"; do
      printf '%s "%s" index %d using 1:2 with steps lw 2 title "render rank %s"' "$sep" "$out/$s/workload.dat" "$i" "${ranks[$i]}"
      sep=", \\"$'\n    '
    done
    echo
  } | gnuplot
  plot_files+=("workload-$s.png")
done

per_scheduler_plot() {  # FILE TITLE XLABEL YLABEL USING [EXTRA]
  {
    plot_setup "$out/$1" "$2 ($runs_caption)"
    echo "set xlabel \"$3\""
    echo "set ylabel \"$4\""
    echo "$6"
    printf 'plot'
    sep=""
    for i in "${!done_list[@]}"; do
      printf '%s "%s" skip 1 using %s with linespoints lw 2 pt 7 ps 0.6 lc %d title "%s"' \
        "$sep" "$out/${done_list[$i]}/frames.csv" "$5" $((i + 1)) "${done_list[$i]}"
      sep=", \\"$'\n    '
    done
    echo
  } | gnuplot
  plot_files+=("$1")
}
per_scheduler_plot frame-time.png "Frame time per frame" "frame" \
  "seconds from first tile handed out to frame composed" '1:4' 'set yrange [0:*]'
# shellcheck disable=SC2016 # $9 is a gnuplot column
per_scheduler_plot bytes-per-frame.png "Cell data sent to render processes per frame" "frame" \
  "MiB per frame (log scale; frames that sent nothing are not drawn)" '1:($9 > 0 ? $9 / 1048576 : NaN)' \
  'set logscale y'
# Imbalance: busy time (solid) and splats (dashed) per scheduler.
{
  plot_setup "$out/imbalance.png" "Per-frame imbalance, max/mean over render processes ($runs_caption)"
  echo 'set xlabel "frame"'
  echo 'set ylabel "max / mean (1 = perfectly balanced)"'
  echo 'set yrange [1:*]'
  printf 'plot'
  sep=""
  for i in "${!done_list[@]}"; do
    f="$out/${done_list[$i]}/frames.csv"
    printf '%s "%s" skip 1 using 1:12 with linespoints lw 2 pt 7 ps 0.6 lc %d title "%s: busy time"' \
      "$sep" "$f" $((i + 1)) "${done_list[$i]}"
    sep=", \\"$'\n    '
    printf '%s "%s" skip 1 using 1:13 with linespoints lw 1 dt 2 pt 6 ps 0.6 lc %d title "%s: splats"' \
      "$sep" "$f" $((i + 1)) "${done_list[$i]}"
  done
  echo
} | gnuplot
plot_files+=(imbalance.png)

render_count="$(awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == "render_processes") c = i; next } NR == 2 { print $c }' "$out/summary.csv")"
steady_from="$(awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == "steady_from") c = i; next } NR == 2 { print $c }' "$out/summary.csv")"
revision="$(git -C "$POINTILLIST_ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)"
if [[ "$revision" != unknown && -n "$(git -C "$POINTILLIST_ROOT" status --porcelain --untracked-files=no 2>/dev/null)" ]]; then
  revision="$revision (with uncommitted changes)"
fi
cpu="$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1)"
{
  echo "# Load-balance benchmark"
  echo
  echo "- dataset: \`$(basename "$dataset")\`, layout $layout (display, traverse, data-send, render), camera path \`$camera\`, $frames frames at $size"
  [[ ${#job_args[@]} -eq 0 ]] || echo "- more job options: \`${job_args[*]}\`"
  for label in "${variant_labels[@]}"; do
    echo "- variant \`$label\`: scheduler ${variant_scheduler[$label]} with \`${variant_options[$label]}\`"
  done
  if ((repeat > 1)); then
    echo "- every entry ran $repeat times, interleaved; the row is the median run by steady frames/s, the range after it is the lowest and highest of the $repeat runs (all runs: \`runs.csv\`)"
  fi
  echo "- $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores (${cpu:-unknown CPU}), $build_type build, revision $revision"
  echo
  echo "$table"
  echo
  echo "- Steady state is frame $steady_from onwards (the first frames fill the caches)."
  echo "- Imbalance is max/mean over the render processes per frame, averaged over the steady frames: 1 is perfect, $render_count means one render process did all the work. \"Imbalance busy (run)\" is the same ratio of each render process's busy time summed over the steady frames: with frames in flight one render may draw frame f+1 while another draws f, so it tells how much of the machine stood idle, which the per-frame figure does not."
  echo "- Splats/s per render process is of wall time in steady state; min and max are over the render processes."
  echo "- Bytes are cell data sent to render processes; cache hits are top-level cells a render process already held when a tile asked for them."
  printf -- '- Load average (1 min) when each run started:'
  for s in "${done_list[@]}"; do printf ' %s %s' "$s" "${load[$s]}"; done
  echo "; a busy machine makes every figure worse and noisier."
  if ((save_frames)); then
    echo "- PNG frames were written (--save-frames): the display's PNG encoding shares the CPU with the job."
  else
    echo "- PNG frames were not written (--save-frames writes them, at a cost in every figure)."
  fi
  echo "- Every figure is in \`summary.csv\` (raw units); per-run CSVs are in each scheduler's directory."
  if ((${#failed[@]} > 0)); then
    echo
    echo "**Failed:** ${failed[*]} (see \`<scheduler>/run.log\`)."
  fi
  echo
  echo "## Plots"
  for p in "${plot_files[@]}"; do
    echo
    echo "![${p%.png}]($p)"
  done
} >"$out/report.md"

echo
echo "$table"
echo
say "report: $out/report.md, figures: $out/summary.csv, plots: ${plot_files[*]}"
if ((${#failed[@]} > 0)); then
  say "FAILED: ${failed[*]}"
  exit 1
fi
