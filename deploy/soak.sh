#!/usr/bin/env bash
# A long run: renders many frames along a path that orbits the scene, leaves
# it (empty frames), comes back close over the surface and does it all again,
# with each render process's cache capped well below what it would hold, and
# watches every process's resident memory and the caches against their cap.
#
#   deploy/soak.sh [--frames N] [--dataset DIR|city] [--layout D,T,S,R]
#                  [--size WxH] [--cache-mb MB] [--out DIR] [ROLE OPTIONS]
#
# Defaults: 10000 frames, the built-in city (2 M points), layout 1,2,1,4,
# 1280x720, a cache cap of 60 % of the dataset's points per render process (a cap
# below one tile's working set cannot hold: README, "Running jobs").
# Writes OUT (out/soak) with the job's statistics, rss.csv (four times a second: time,
# pid, role, rank, VmRSS and VmHWM in KiB), memory.png (resident memory per
# process over time), cache.png (each render process's cache against the cap)
# and prints the verdict against the goals:
#   - resident memory of every process grows less than 5 % after warm-up
#     (the first 10 % of the run; compared: the mean over 10-20 % of the run
#     against the mean over its last 10 %),
#   - no render cache above its cap,
#   - every frame complete, no tile lost (failed).
# Exit code 0 when all hold, 1 otherwise.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

frames=10000
dataset=city
layout=1,2,1,4
size=1280x720
cache_mb=""
out="$POINTILLIST_ROOT/out/soak"
role_args=()
while (($#)); do
  case "$1" in
    --frames) frames="$2"; shift 2 ;;
    --dataset) dataset="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --cache-mb) cache_mb="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,22p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) role_args+=("$1"); shift ;;
  esac
done
die() { echo "soak.sh: $*" >&2; exit 2; }
[[ "$frames" =~ ^[0-9]+$ ]] && ((frames >= 20)) || die "--frames must be a number of at least 20"

install_packages
command -v gnuplot >/dev/null || die "gnuplot is missing (Debian package gnuplot-nox)"
build_all
if [[ "$dataset" == "city" ]]; then
  dataset="$POINTILLIST_ROOT/datasets/city-2000000"
  ensure_city_dataset "$dataset" 2000000
fi
[[ -f "$dataset/manifest.txt" ]] || die "'$dataset' is not a dataset (no manifest.txt)"
points_bytes=$(awk '$1 == "file.points" { print $4 }' "$dataset/manifest.txt")
if [[ -z "$cache_mb" ]]; then
  cache_mb=$(awk -v b="$points_bytes" 'BEGIN { printf "%.0f", b * 0.6 / 1048576 }')
fi
mkdir -p "$out"
rm -f "$out"/frame_*.png

# The path: a cycle of 1000 frames (orbit, fly out looking away, fly back in,
# low pass over the surface), repeated, so every view comes back ten times in
# 10000 frames while the caches must let go of what the others need.
python3 - "$dataset/manifest.txt" "$frames" >"$out/path.txt" <<'PY'
import math, sys
manifest = dict(line.split(" = ", 1) for line in open(sys.argv[1]).read().splitlines()
                if " = " in line and not line.startswith("#"))
lo = [float(v) for v in manifest["bounds_min"].split()]
hi = [float(v) for v in manifest["bounds_max"].split()]
frames = int(sys.argv[2])
c = [(a + b) / 2 for a, b in zip(lo, hi)]
r = math.dist(lo, hi) / 2
thin = min(range(3), key=lambda i: hi[i] - lo[i])   # the up axis: the thinnest
up = [1.0 if i == thin else 0.0 for i in range(3)]
a1, a2 = [i for i in range(3) if i != thin]
def point(radius, azimuth, height):
    p = list(c)
    p[a1] += radius * math.cos(azimuth)
    p[a2] += radius * math.sin(azimuth)
    p[thin] += height
    return p
print("# soak path: eye(x y z) target(x y z) up(x y z) fovY")
for i in range(frames):
    k = i % 1000
    turn = 2 * math.pi * (i // 1000) * 0.37        # each cycle starts elsewhere
    if k < 400:                                     # orbit
        az = turn + 2 * math.pi * k / 400
        eye, target = point(1.6 * r, az, 0.6 * r), c
    elif k < 500:                                   # out, looking away: empty frames
        s = (k - 400) / 100
        az = turn
        eye = point((1.6 + 8 * s) * r, az, 0.6 * r)
        target = point((3 + 8 * s) * r, az, 0.6 * r)
    elif k < 600:                                   # back in, looking at the scene
        s = (k - 500) / 100
        az = turn + 0.5
        eye, target = point((9.6 - 8.6 * s) * r, az, (0.6 - 0.4 * s) * r), c
    else:                                           # low pass over the surface
        s = (k - 600) / 400
        az = turn + 0.5 + math.pi * s
        eye = point(0.9 * r * (1 - s) + 0.3 * r * s, az, 0.2 * r)
        target = point(0.5 * r * (1 - s), az + math.pi, 0.0)
    print(" ".join(f"{v:.4f}" for v in (*eye, *target, *up)), 45)
PY

# Resident memory of every process of the job, four times a second.
sampler() {
  python3 - "$out/rss.csv" <<'PY'
import os, sys, time
out = open(sys.argv[1], "w", buffering=1)
out.write("t,pid,role,rank,rss_kib,hwm_kib\n")
seen = False
while True:
    now, found = time.time(), 0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            # comm is cut at 15 characters: the executable's name instead
            argv0 = open(f"/proc/{pid}/cmdline", "rb").read().split(b"\0")[0].decode()
            comm = os.path.basename(argv0)
            if not comm.startswith("pointillist-") or comm == "pointillist-soak":
                continue
            fields = dict(line.split(":", 1) for line in open(f"/proc/{pid}/status"))
            env = open(f"/proc/{pid}/environ", "rb").read().split(b"\0")
            rank = next((e.split(b"=", 1)[1].decode() for e in env
                         if e.startswith(b"OMPI_COMM_WORLD_RANK=")), "")
        except (OSError, ValueError):
            continue
        if not rank:
            continue  # not a rank of an MPI job (a tool run beside it)
        found += 1
        rss = int(fields["VmRSS"].split()[0])
        hwm = int(fields["VmHWM"].split()[0])
        out.write(f"{now:.3f},{pid},{comm[len('pointillist-'):]},{rank},{rss},{hwm}\n")
    seen = seen or found > 0
    if seen and found == 0:
        break
    time.sleep(0.25)
PY
}
sampler &
sampler_pid=$!
trap 'kill "$sampler_pid" 2>/dev/null || true' EXIT

log "soak: $frames frames of $(basename "$dataset") at $size, layout $layout, cache cap $cache_mb MiB per render process"
started=$(date +%s)
set +e
bash "$POINTILLIST_ROOT/deploy/run.sh" --layout "$layout" --dataset "$dataset" \
  --camera-path "$out/path.txt" --frames "$frames" --size "$size" --cache-mb "$cache_mb" \
  --quiet --stats "$out/stats.json" "${role_args[@]}" >"$out/job.log" 2>&1
code=$?
set -e
wait "$sampler_pid" 2>/dev/null || true
trap - EXIT
grep -v '^  ' "$out/job.log" | tail -n 20
log "soak: the job took $(($(date +%s) - started)) s and exited with code $code"

# The verdict, and the plots' data.
verdict=0
python3 - "$out" "$cache_mb" "$frames" "$code" <<'PY' || verdict=$?
import collections, csv, json, pathlib, sys
out, cap_mib, frames_wanted, code = pathlib.Path(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
rows = list(csv.DictReader(open(out / "rss.csv")))
t0 = min(float(r["t"]) for r in rows)
t1 = max(float(r["t"]) for r in rows)
span = t1 - t0
by_process = collections.defaultdict(list)
for r in rows:
    by_process[(r["role"], int(r["rank"] or -1), r["pid"])].append((float(r["t"]) - t0, int(r["rss_kib"])))
ok = code == 0
print(f"\nresident memory (MiB): mean over 10-20 % of the run, over its last 10 %, growth; peak (VmHWM)")
worst = 0.0
with open(out / "rss.dat", "w") as dat:
    for (role, rank, pid), samples in sorted(by_process.items(), key=lambda kv: kv[0][1]):
        def mean(a, b):
            v = [rss for t, rss in samples if a * span <= t <= b * span]
            return sum(v) / len(v) if v else float("nan")
        warm, end = mean(0.10, 0.20), mean(0.90, 1.0)
        if not (warm > 0 and end > 0):
            print(f"  {role} rank {rank}: too few samples to judge (a longer run is needed)")
            ok = False
            continue
        growth = (end - warm) / warm * 100
        worst = max(worst, growth)
        hwm = max(int(r["hwm_kib"]) for r in rows if r["pid"] == pid)
        print(f"  {role:9s} rank {rank:2d}: {warm / 1024:8.1f} -> {end / 1024:8.1f}  {growth:+6.2f} %;"
              f" peak {hwm / 1024:.1f}")
        dat.write(f"# {role} rank {rank}\n")
        for t, rss in samples:
            dat.write(f"{t:.1f},{rss / 1024:.2f}\n")
        dat.write("\n\n")
stats = json.loads((out / "stats.json").read_text())
k = stats["key_figures"]  # exact; the per-frame records of a long run are thinned
frames = k["frames"]
failed = k["failed_tiles"]
reissued = k["reissued_tiles"]
cache = list(csv.DictReader(open(out / "renders.csv")))
peak_cache = max(int(r["cache_bytes"]) for r in cache) / 1048576
evictions = max(int(r["evictions"]) for r in cache)
print(f"frames: {frames} of {frames_wanted} in {stats['total_seconds']:.0f} s "
      f"({frames / stats['total_seconds']:.1f} frames/s); tiles re-issued {reissued}, failed {failed}")
print(f"render caches: peak {peak_cache:.1f} MiB against a cap of {cap_mib:.0f} MiB; "
      f"{evictions} evictions on the busiest render process")
checks = [
    (worst < 5.0, f"resident memory growth after warm-up below 5 % (worst {worst:+.2f} %)"),
    (peak_cache <= cap_mib, f"render caches never above their cap ({peak_cache:.1f} <= {cap_mib:.0f} MiB)"),
    (evictions > 0, "the cap was below what the path needs (evictions happened)"),
    (frames == frames_wanted and failed == 0, f"every frame complete, no tile lost"),
]
for good, text in checks:
    print(("PASS " if good else "FAIL ") + text)
    ok = ok and good
with open(out / "cache.dat", "w") as dat:
    for rank in sorted({r["render_rank"] for r in cache}, key=int):
        dat.write(f"# render rank {rank}\n")
        for r in cache:
            if r["render_rank"] == rank:
                dat.write(f"{float(r['t']):.2f},{int(r['cache_bytes']) / 1048576:.2f}\n")
        dat.write("\n\n")
(out / "labels.txt").write_text("\n".join(f"{role} rank {rank}" for role, rank, _ in
                                          sorted(by_process, key=lambda p: p[1])) + "\n")
sys.exit(0 if ok else 1)
PY

mapfile -t labels <"$out/labels.txt"
{
  echo 'set terminal pngcairo size 1100,620 font "sans,11" noenhanced'
  echo "set output \"$out/memory.png\""
  echo "set title \"Resident memory per process: $frames frames, $(basename "$dataset"), layout $layout, cache cap $cache_mb MiB\""
  echo 'set datafile separator ","'
  echo 'set key outside right top box'
  echo 'set grid'
  echo 'set xlabel "time since the job started (s)"'
  echo 'set ylabel "VmRSS (MiB)"'
  echo 'set yrange [0:*]'
  printf 'plot'
  sep=""
  for i in "${!labels[@]}"; do
    printf '%s "%s" index %d using 1:2 with lines lw 2 title "%s"' "$sep" "$out/rss.dat" "$i" "${labels[$i]}"
    sep=","
  done
  echo
} | gnuplot
mapfile -t renders < <(awk -F, 'NR > 1 && !seen[$3]++ { print $3 }' "$out/renders.csv" | sort -n)
{
  echo 'set terminal pngcairo size 1100,620 font "sans,11" noenhanced'
  echo "set output \"$out/cache.png\""
  echo "set title \"Render caches against the cap ($cache_mb MiB)\""
  echo 'set datafile separator ","'
  echo 'set key outside right top box'
  echo 'set grid'
  echo 'set xlabel "time since the run began (s)"'
  echo 'set ylabel "cache (MiB)"'
  echo 'set yrange [0:*]'
  printf 'plot %s with lines dt 2 lw 2 lc rgb "red" title "cap"' "$cache_mb"
  for i in "${!renders[@]}"; do
    printf ', "%s" index %d using 1:2 with steps lw 1 title "render rank %s"' "$out/cache.dat" "$i" "${renders[$i]}"
  done
  echo
} | gnuplot
log "soak: plots $out/memory.png and $out/cache.png; samples $out/rss.csv"
exit "$verdict"
