#!/usr/bin/env bash
# Preprocess throughput benchmark: samples a mesh to POINTS surface points
# (default 10 million), builds a dataset with pointillist-preprocess from a
# Release build and prints points/second, wall time and peak memory.
#
#   deploy/bench-preprocess.sh [MESH] [POINTS] [-- extra pointillist-preprocess options]
#
# MESH defaults to the Stanford bunny from libcgal-demo (unpacked by
# deploy/fetch-test-data.sh). Environment:
#   POINTILLIST_BENCH_BUILD  build directory (default: build-release; configured as Release)
#   POINTILLIST_BENCH_OUT    where the dataset goes (default: out/bench-preprocess)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${POINTILLIST_BENCH_BUILD:-$root/build-release}"
out="${POINTILLIST_BENCH_OUT:-$root/out/bench-preprocess}"

mesh="$root/.cache/cgal-data/data/meshes/bunny00.off"
points=10000000
if [[ $# -gt 0 && "$1" != "--" ]]; then mesh="$1"; shift; fi
if [[ $# -gt 0 && "$1" != "--" ]]; then points="$1"; shift; fi
if [[ $# -gt 0 && "$1" == "--" ]]; then shift; fi

if [[ ! -f "$mesh" && "$mesh" == "$root/.cache/cgal-data/"* ]]; then
  bash "$root/deploy/fetch-test-data.sh"
fi
[[ -f "$mesh" ]] || { echo "bench-preprocess: no mesh at $mesh" >&2; exit 1; }

if [[ ! -f "$build/CMakeCache.txt" ]]; then
  echo "bench-preprocess: configuring a Release build in $build" >&2
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
fi
build_type="$(sed -n 's/^CMAKE_BUILD_TYPE:[A-Z]*=//p' "$build/CMakeCache.txt")"
[[ "$build_type" == "Release" ]] || echo "bench-preprocess: warning: $build is a '$build_type' build" >&2
cmake --build "$build" --target pointillist-preprocess -j "$(nproc)" >/dev/null

mkdir -p "$(dirname "$out")"
rm -rf "$out"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
echo "bench-preprocess: $(basename "$mesh") sampled to $points points, $(nproc) cores ($build_type)" >&2
/usr/bin/time -f '%e %M %U %S' -o "$log.time" \
  "$build/bin/pointillist-preprocess" "$mesh" --points "$points" -o "$out" "$@" | tee "$log"
read -r wall rss_kib user sys <"$log.time"
rm -f "$log.time"
bytes="$(du -sb "$out" | cut -f1)"
# CPU time is printed too: on a busy machine it is the steadier figure.
awk -v p="$points" -v w="$wall" -v r="$rss_kib" -v b="$bytes" -v u="$user" -v s="$sys" 'BEGIN {
  printf "bench-preprocess: %d points in %.2f s wall = %.0f points/s end to end (CPU %.2f s user + %.2f s sys); peak RSS %.0f MiB; dataset %.0f MiB\n",
    p, w, p / w, u, s, r / 1024, b / 1048576 }'
