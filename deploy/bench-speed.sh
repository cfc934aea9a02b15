#!/usr/bin/env bash
# Interactive-speed benchmark (the goals of "30 frames/s on a 10 M-point scan"):
# for each scene, the job and the single-process reference on the same frames,
# with a quality figure for the level of detail, and where the CPU goes.
#
#   deploy/bench-speed.sh [--scenes bunny-10M,city] [--layout 1,2,1,4] [--frames 48]
#       [--size 1280x720] [--camera-path orbit] [--loops 2] [--repeat 1] [--out DIR]
#       [-- options for both job and reference, e.g. --lod-pixels 2 --renderer gl]
#
# Scenes: bunny-10M is Debian's bunny00.off (libcgal-demo) sampled to 10 M
# points with normals; city is the built-in generated scene (2 M points). Both
# are made once into datasets/. Per scene it prints one table: goal, measured,
# met; the job's CPU per role and activity; and writes OUT/<scene>/ (stats.json
# of each job run, reference-N.log, and two plots: bytes.png, MiB moved by each
# frame of the median job run; pairs.png, frames/s of each job and reference
# pair) and OUT/goals.md with every table.
# --loops N plays the path N times over (job and reference alike). The bytes
# goal is judged on the loops after the first: in the first, a 48-frame orbit
# of the bunny reveals about 2.5 % of the first frame's bytes each frame to
# any scheduler (docs/scheduling.md §19), so the first loop is the warm-up;
# its steady bytes, and that floor (pointillist-bench-walk --working-set),
# are printed beside them. --loops 1 gives the one-loop table.
# --repeat N runs the job and the reference in turn N times; it reports the job
# run with the median steady frame rate, the median reference, and job over
# reference as the median of the N back-to-back pairs (this machine's speed
# drifts by a fifth within minutes; see the ranges printed beside them).
# Environment: POINTILLIST_BUILD (default build-release, configured as Release).
set -euo pipefail
# Chosen before common.sh, which would default it to the RelWithDebInfo build.
export POINTILLIST_BUILD="${POINTILLIST_BUILD:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/build-release}"
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
POINTILLIST_BIN="$POINTILLIST_BUILD/bin"

scenes="bunny-10M,city"
layout="1,2,1,4"
frames=48
size="1280x720"
camera_path="orbit"
loops=2
repeat=1
out="$POINTILLIST_ROOT/out/bench-speed"
extra=()
die() { echo "bench-speed: $*" >&2; exit 2; }
while (($#)); do
  case "$1" in
    --scenes) scenes="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --camera-path) camera_path="$2"; shift 2 ;;
    --loops) loops="$2"; shift 2 ;;
    --repeat) repeat="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,27p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) die "unknown option '$1' (options for the job and reference go after --)" ;;
  esac
done
[[ "$frames" =~ ^[1-9][0-9]*$ ]] || die "--frames '$frames' is not a positive count"
[[ "$loops" =~ ^[1-9][0-9]*$ ]] || die "--loops '$loops' is not a positive count"
[[ "$repeat" =~ ^[1-9][0-9]*$ ]] || die "--repeat '$repeat' is not a positive count"
[[ "$size" =~ ^[1-9][0-9]*x[1-9][0-9]*$ ]] || die "--size '$size' is not WIDTHxHEIGHT"

install_packages
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
if [[ ! -f "$POINTILLIST_BUILD/CMakeCache.txt" ]]; then
  log "configuring a Release build in $POINTILLIST_BUILD"
  cmake -S "$POINTILLIST_ROOT" -B "$POINTILLIST_BUILD" -DCMAKE_BUILD_TYPE=Release \
    -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
cmake --build "$POINTILLIST_BUILD" -j "$(nproc)" >/dev/null
use_malloc_tuning  # the job's; the reference runs with reference_malloc_tunables

mkdir -p "$out"
report="$out/goals.md"
{
  echo "# bench-speed: $(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, layout $layout, $size, $camera_path, $frames frames x $loops loops"
  echo "options: ${extra[*]:-(defaults)}; commit $(git -C "$POINTILLIST_ROOT" rev-parse --short HEAD 2>/dev/null || echo '?')"
} >"$report"

IFS=, read -r -a scene_list <<<"$scenes"
for scene in "${scene_list[@]}"; do
  dataset=$(scene_dataset "$scene")
  dir="$out/$scene"
  mkdir -p "$dir"
  # Job and reference in turn, so each ratio pairs runs the machine's drift
  # touched alike (it moves either by a fifth within minutes here).
  for ((run = 1; run <= repeat; run++)); do
    log "$scene: job run $run of $repeat, then the reference"
    bash "$POINTILLIST_ROOT/deploy/run.sh" --layout "$layout" --dataset "$dataset" \
      --camera-path "$camera_path" --frames "$frames" --loops "$loops" --size "$size" --quiet \
      --stats "$dir/stats-$run.json" "${extra[@]}" >"$dir/job-$run.log" 2>&1 ||
      { cat "$dir/job-$run.log" >&2; die "$scene: the job failed (log above)"; }
    GLIBC_TUNABLES="$(reference_malloc_tunables)" \
      "$POINTILLIST_BIN/pointillist-reference" --dataset "$dataset" --camera-path "$camera_path" \
      --frames "$frames" --loops "$loops" --size "$size" "${extra[@]}" \
      >"$dir/reference-$run.log" 2>&1 ||
      { cat "$dir/reference-$run.log" >&2; die "$scene: the reference failed"; }
  done
  log "$scene: the reference's frames at full detail, for the quality figures"
  "$POINTILLIST_BIN/pointillist-reference" --dataset "$dataset" --camera-path "$camera_path" \
    --frames "$frames" --size "$size" --quality "${extra[@]}" >"$dir/quality.log" 2>&1 ||
    { cat "$dir/quality.log" >&2; die "$scene: the quality run failed"; }
  # What the view itself reveals each frame of the first loop, to one render
  # holding every tile: the floor under the first loop's steady bytes.
  "$POINTILLIST_BIN/pointillist-bench-walk" --dataset "$dataset" --camera-path "$camera_path" \
    --frames "$frames" --size "$size" --tiles 8x4 --working-set --repeat 1 "${extra[@]}" \
    >"$dir/working-set.log" 2>&1 || log "$scene: pointillist-bench-walk failed (see $dir/working-set.log)"
  python3 - "$scene" "$dir" "$repeat" "$dataset" >>"$report" <<'EOF'
import json, re, statistics, sys
scene, folder, repeat, dataset = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
runs = [json.load(open(f"{folder}/stats-{i}.json")) for i in range(1, repeat + 1)]
fps = [r["key_figures"]["frames_per_second_steady"] for r in runs]
median = sorted(range(len(runs)), key=lambda i: fps[i])[len(runs) // 2]
k = runs[median]["key_figures"]
refs = []
for i in range(1, repeat + 1):
    m = re.search(r"reference: \d+ frames, ([0-9.]+) frames/s, ([0-9.]+) M splats/s rendering \(([0-9.]+) M splats per frame\)",
                  open(f"{folder}/reference-{i}.log").read())
    refs.append((float(m.group(1)), float(m.group(3))))
ref_all = [f for f, _ in refs]
ref_fps = statistics.median(ref_all)
ref_splats = refs[0][1]
# Job over reference run by run (each pair ran back to back), then the median.
ratios = [j / r for j, r in zip(fps, ref_all)]
ratio = statistics.median(ratios)
with open(f"{folder}/bytes.tsv", "w") as out:  # frame, MiB sent for it
    for f in runs[median]["frames"]:
        out.write(f"{f['frame']}\t{f['bytes_sent'] / 2**20:.4f}\n")
with open(f"{folder}/pairs.tsv", "w") as out:  # pair, job frames/s, reference frames/s
    for i, (j, r) in enumerate(zip(fps, ref_all), 1):
        out.write(f"{i}\t{j:.3f}\t{r:.3f}\n")
q = open(f"{folder}/quality.log").read()
qm = re.search(r"quality: mean PSNR ([0-9.]+) dB over (\d+) frame.*?\((\d+) identical\), ([0-9.]+)% of covered", q)
full = re.findall(r"full detail ([0-9.]+) M splats", q)
full_splats = sum(map(float, full)) / len(full) if full else 0.0
first = k["bytes_first_frame"] / 2**20
steady = k["bytes_per_frame_steady"] / 2**20
later_from = k.get("later_loops_from", 0)
later = k.get("bytes_per_frame_later_loops", 0) / 2**20
# The first loop's steady frames, from the per-frame detail (kept whole here).
first_loop = [f["bytes_sent"] for f in runs[median]["frames"]
              if k["steady_from"] <= f["frame"] < (later_from or k["frames"])]
first_loop_steady = sum(first_loop) / len(first_loop) / 2**20 if first_loop else 0.0
# The floor: "tiles ranges first later share ..." of pointillist-bench-walk --working-set.
floor = None
try:
    lines = open(f"{folder}/working-set.log").read().splitlines()
    at = next(i for i, l in enumerate(lines) if l.startswith("one render process holding every tile"))
    fields = lines[at + 2].split()
    floor = (float(fields[3]), fields[4])
except (OSError, StopIteration, IndexError, ValueError):
    pass
rows = [
    ("job frames/s (steady)", f"{k['frames_per_second_steady']:.2f}" + (f" (runs {min(fps):.2f}-{max(fps):.2f})" if repeat > 1 else ""), ">= 30", k["frames_per_second_steady"] >= 30),
    ("reference frames/s", f"{ref_fps:.2f}" + (f" (median; runs {min(ref_all):.2f}-{max(ref_all):.2f})" if repeat > 1 else ""), ">= 60", ref_fps >= 60),
    ("job / reference", f"{ratio:.2f}" + (f" (median of {repeat} pairs run back to back; {min(ratios):.2f}-{max(ratios):.2f})" if repeat > 1 else ""), ">= 0.9", ratio >= 0.9),
    ("splats per frame (job / reference / full detail)", f"{k['splats_per_frame'] / 1e6:.2f} M / {ref_splats:.2f} M / {full_splats:.2f} M", "~ covered pixels", None),
    ("quality vs full detail", f"PSNR {qm.group(1)} dB, {qm.group(4)} % of covered pixels identical", "shown", None),
    ("bytes first frame", f"{first:.1f} MiB", "only the LOD drawn", None),
]
later_loops = ("loop 2" if k["frames"] // later_from == 2 else f"loops 2-{k['frames'] // later_from}") if later_from else ""
if later_from:
    rows += [
        ("bytes per frame, first loop from frame %d (the warm-up)" % k["steady_from"], f"{first_loop_steady:.2f} MiB ({100 * first_loop_steady / first if first else 0:.1f} % of first)", "", None),
        ("floor: what the view reveals a frame (one render holding every tile)", f"{floor[0]:.2f} MiB ({floor[1]} of its own first frame)" if floor else "n/a", "", None),
        (f"bytes per frame after warm-up ({later_loops})", f"{later:.3f} MiB ({100 * later / first if first else 0:.2f} % of first)", "<= 2 %", first > 0 and later <= 0.02 * first),
        ("of it, another render held (work moved)", f"{k.get('bytes_held_elsewhere_per_frame_later_loops', 0) / 2**20:.3f} MiB", "", None),
        (f"job frames/s, {later_loops}", f"{k.get('frames_per_second_later_loops', 0):.2f}", "", None),
    ]
else:
    rows += [
        ("bytes per frame steady", f"{steady:.2f} MiB ({100 * steady / first if first else 0:.1f} % of first)", "<= 2 %", first > 0 and steady <= 0.02 * first),
        ("of it, another render held (work moved)", f"{k.get('bytes_held_elsewhere_per_frame_steady', 0) / 2**20:.2f} MiB", "", None),
    ]
rows += [
    ("cache hit rate steady", f"{100 * k['cache_hit_rate_steady']:.1f} %", "", None),
    ("CPU per frame", f"{1e3 * k['cpu_per_frame_total']:.0f} core-ms (display {1e3 * k['cpu_per_frame_display']:.0f}, traverse {1e3 * k['cpu_per_frame_traverse']:.0f}, data-send {1e3 * k['cpu_per_frame_datasend']:.0f}, render {1e3 * k['cpu_per_frame_render']:.0f}, of which drawing {1e3 * k['draw_per_frame']:.0f})", "", None),
]
print(f"\n## {scene} ({dataset})\n")
print("| figure | measured | goal | met |\n|---|---|---|---|")
for name, value, goal, met in rows:
    print(f"| {name} | {value} | {goal} | {'' if met is None else ('yes' if met else 'no')} |")
print("\nCPU per frame by role and activity, core-ms (whole run, warm-up included):\n")
by_role = {}
frames = k["frames"]
for p in runs[median]["processes"]:
    acts = by_role.setdefault(p["role"], {})
    covered = 0.0
    for a, s in p.get("activities", {}).items():
        acts[a] = acts.get(a, 0.0) + s
        covered += s
    acts["other threads"] = acts.get("other threads", 0.0) + max(0.0, p["cpu_seconds"] - covered)
for role, acts in sorted(by_role.items()):
    parts = ", ".join(f"{a} {1e3 * s / frames:.1f}" for a, s in sorted(acts.items(), key=lambda x: -x[1]) if s > 0)
    print(f"- {role}: {parts}")
EOF
  gnuplot <<PLOT
set terminal pngcairo size 1000,480
set output "$dir/bytes.png"
set title "$scene: MiB moved by each frame (median job run; layout $layout, $size, $camera_path)"
set xlabel "frame"
set ylabel "MiB (log scale)"
set logscale y
set grid
plot "$dir/bytes.tsv" using 1:(\$2 > 0 ? \$2 : 1/0) with linespoints pt 7 ps 0.5 title "bytes sent"
PLOT
  gnuplot <<PLOT
set terminal pngcairo size 1000,480
set output "$dir/pairs.png"
set title "$scene: frames/s of each back-to-back pair (steady job; reference)"
set xlabel "pair"
set ylabel "frames/s"
set yrange [0:*]
set xtics 1
set grid
plot "$dir/pairs.tsv" using 1:2 with linespoints pt 7 title "job", \\
     "$dir/pairs.tsv" using 1:3 with linespoints pt 5 title "reference"
PLOT
done
cat "$report"
log "report in $report"
