#!/usr/bin/env bash
# Fuzzes Pointillist's input surfaces with libFuzzer under ASan and UBSan, by
# hand (not in ctest):
#
#   deploy/fuzz.sh [SECONDS per target, default 60] [TARGET ...]
#
# Targets: fuzz_ply, fuzz_xyz, fuzz_las, fuzz_off (pointillist-preprocess's
# readers), fuzz_dataset_manifest (the manifest every role reads first; what
# parses must print and parse again the same) and fuzz_service_request (every
# client message's parser and checks). Installs clang and libFuzzer when missing, builds them in
# build-fuzz/ (only what they need), seeds each corpus from real files
# (libcgal-demo's scans and meshes, cut to 32 KiB; a small LAS file written
# here; service requests the Python client's module makes) and runs each
# target for SECONDS on one core. Prints executions and coverage per target;
# a crash, hang (over 10 s) or sanitizer report stops that target and its
# input lands in out/fuzz/TARGET/ (replay: build-fuzz/bin/TARGET FILE).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

seconds="${1:-60}"
shift || true
targets=("$@")
((${#targets[@]})) ||
  targets=(fuzz_ply fuzz_xyz fuzz_las fuzz_off fuzz_dataset_manifest fuzz_service_request)

POINTILLIST_PACKAGES+=(clang libfuzzer-14-dev)
install_packages
bash "$POINTILLIST_ROOT/deploy/fetch-test-data.sh"

build="$POINTILLIST_ROOT/build-fuzz"
out="$POINTILLIST_ROOT/out/fuzz"
mkdir -p "$out"
if [[ ! -f "$build/CMakeCache.txt" ]]; then
  log "configuring the fuzz build (clang, ASan + UBSan) in $build"
  CC=clang CXX=clang++ cmake -S "$POINTILLIST_ROOT" -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPOINTILLIST_FUZZ=ON -DPOINTILLIST_SANITIZE=address,undefined \
    -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
else
  cmake "$build" >/dev/null  # targets added since
fi
log "building ${targets[*]} (log: $build/build.log)"
if ! cmake --build "$build" -j "$(nproc)" --target "${targets[@]}" pointillist_proto_python \
    >"$build/build.log" 2>&1; then
  tail -n 40 "$build/build.log" >&2
  exit 1
fi

data="$POINTILLIST_ROOT/.cache/cgal-data/data"
# Seeds: real files of the target's format, the first 32 KiB of each.
seed_files() {
  local dir="$1" pattern="$2" file
  mkdir -p "$dir"
  find "$data" -iname "$pattern" -size -4M | sort | head -n 40 | while read -r file; do
    head -c 32768 "$file" >"$dir/$(basename "$file")"
  done
}
# A small LAS 1.2 file (point format 2: XYZ, intensity, RGB) as the LAS seed.
write_las_seed() {
  /usr/bin/python3 - "$1/seed.las" <<'PY'
import struct, sys
points = [(i * 100, (i * 37) % 500, (i * 11) % 300, i * 600 % 65536) for i in range(64)]
record = 26
header = bytearray(227)
header[0:4] = b"LASF"
struct.pack_into("<BB", header, 24, 1, 2)                     # version 1.2
struct.pack_into("<H", header, 94, 227)                       # header size
struct.pack_into("<I", header, 96, 227)                       # offset to points
struct.pack_into("<IBH", header, 100, 0, 2, record)           # VLRs, format, record length
struct.pack_into("<I", header, 107, len(points))              # legacy point count
struct.pack_into("<ddd", header, 131, 0.01, 0.01, 0.01)       # scale
struct.pack_into("<ddd", header, 155, 0.0, 0.0, 0.0)          # offset
struct.pack_into("<dddddd", header, 179, 6.4, 0.0, 5.0, 0.0, 3.0, 0.0)  # max/min x y z
body = b"".join(struct.pack("<iiiHBBbBHHHH", x, y, z, 100, 0, 0, 0, 0, 0, c, c // 2, 65535 - c)
                for x, y, z, c in points)
open(sys.argv[1], "wb").write(bytes(header) + body)
PY
}
# Requests as clients send them, from the service's own protobuf module.
write_request_seeds() {
  PYTHONPATH="$POINTILLIST_ROOT/clients/python" POINTILLIST_PYTHON="$build/python" \
    /usr/bin/python3 - "$1" <<'PY' ||
import sys
from pointillist_client import pb
out = sys.argv[1]
v = pb.SERVICE_VERSION_CURRENT
cam = pb.CameraKey(eye=pb.Vec3(x=1, y=2, z=3), target=pb.Vec3(x=0, y=0, z=0), fov_y_degrees=45)
requests = {
    "hello": pb.Request(version=v, request_id=1, hello=pb.Hello(client_name="fuzz")),
    "attach": pb.Request(version=v, client_id="c1", request_id=2, attach=pb.AttachRequest()),
    "render": pb.Request(version=v, client_id="c1", request_id=3,
                         render=pb.RenderRequest(camera=cam, format=pb.FrameFormat(
                             width=640, height=360, encoding=pb.ENCODING_JPEG, jpeg_quality=80))),
    "path": pb.Request(version=v, client_id="c1", request_id=4,
                       path=pb.PathRequest(builtin="orbit", frames=10)),
    "stats": pb.Request(version=v, client_id="c1", request_id=5, stats=pb.StatsRequest()),
    "options": pb.Request(version=v, client_id="c1", request_id=6,
                          set_options=pb.SetOptionsRequest(mode="splats", lod_pixels=2.0)),
}
for name, request in requests.items():
    open(f"{out}/{name}", "wb").write(request.SerializeToString())
PY
    log "no Python protobuf module: the service corpus starts empty"
}

printf '%-22s %12s %10s %8s %s\n' target executions "exec/s" coverage result >"$out/summary.txt"
status=0
for target in "${targets[@]}"; do
  corpus="$out/$target/corpus"
  mkdir -p "$corpus"
  case "$target" in
    fuzz_ply) seed_files "$corpus" '*.ply' ;;
    fuzz_xyz) seed_files "$corpus" '*.xyz'; seed_files "$corpus" '*.pwn' ;;
    fuzz_off) seed_files "$corpus" '*.off' ;;
    fuzz_las) write_las_seed "$corpus" ;;
    fuzz_dataset_manifest)
      # Manifests of the datasets made here, and of the built-in city.
      find "$POINTILLIST_ROOT/datasets" "$POINTILLIST_ROOT/build" -maxdepth 3 -name manifest.txt \
        2>/dev/null | head -n 10 | while read -r file; do
        cp "$file" "$corpus/$(echo "$file" | md5sum | cut -c1-12)"
      done ;;
    fuzz_service_request) write_request_seeds "$corpus" ;;
  esac
  log "$target: $seconds s from $(ls "$corpus" | wc -l) inputs"
  result=ok
  if ! (cd "$out/$target" && "$build/bin/$target" "$corpus" -max_total_time="$seconds" \
      -timeout=10 -rss_limit_mb=4096 -max_len=65536 -print_final_stats=1 \
      -artifact_prefix="$out/$target/" >"$out/$target/log.txt" 2>&1); then
    result="FINDING: $(ls "$out/$target"/crash-* "$out/$target"/timeout-* "$out/$target"/leak-* \
      "$out/$target"/oom-* 2>/dev/null | head -n 1)"
    status=1
  fi
  runs=$(grep -Eo 'stat::number_of_executed_units: +[0-9]+' "$out/$target/log.txt" | grep -Eo '[0-9]+$' || echo 0)
  rate=$(grep -Eo 'stat::average_exec_per_sec: +[0-9]+' "$out/$target/log.txt" | grep -Eo '[0-9]+$' || echo 0)
  cov=$(grep -Eo 'cov: [0-9]+' "$out/$target/log.txt" | tail -n 1 | grep -Eo '[0-9]+' || echo 0)
  printf '%-22s %12s %10s %8s %s\n' "$target" "$runs" "$rate" "$cov" "$result" >>"$out/summary.txt"
done
echo
cat "$out/summary.txt"
echo "logs, corpora and findings in $out"
exit "$status"
