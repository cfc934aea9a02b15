#!/usr/bin/env bash
# Render-path benchmark: splats/second of each path (points / splats mode x
# compatibility / core GL profile) at 1280x720 and 1920x1080, for random and
# for spatially clustered splats, on Mesa llvmpipe through OSMesa, and of the
# CPU point kernel. Each case runs whole-frame (tiles 1x1) and as the job
# draws (8x4 tiles, each from the splats that reach it, into a tile-sized
# buffer; every tile checked against the whole frame); --tiles changes that.
#
#   deploy/bench-render.sh [-- extra pointillist-bench-render options]
#   e.g. deploy/bench-render.sh -- --count 5000000 --paths points/compat
#
# It runs the table twice: with llvmpipe using every core (LP_NUM_THREADS
# unset), and single-threaded (LP_NUM_THREADS=1, i.e. per render process when
# several share a machine). Environment:
#   POINTILLIST_BENCH_BUILD  build directory (default: build-release; configured as Release)
#   POINTILLIST_BENCH_THREADS  "all", "1" or "all 1" (default: "all 1")
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${POINTILLIST_BENCH_BUILD:-$root/build-release}"
threads="${POINTILLIST_BENCH_THREADS:-all 1}"
if [[ $# -gt 0 && "$1" == "--" ]]; then shift; fi

if [[ ! -f "$build/CMakeCache.txt" ]]; then
  echo "bench-render: configuring a Release build in $build" >&2
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
cmake --build "$build" --target pointillist-bench-render -j "$(nproc)" >/dev/null

echo "bench-render: $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
for t in $threads; do
  if [[ "$t" == "all" ]]; then
    env -u LP_NUM_THREADS "$build/bin/pointillist-bench-render" "$@"
  else
    LP_NUM_THREADS="$t" "$build/bin/pointillist-bench-render" "$@"
  fi
  echo
done
