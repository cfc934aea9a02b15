#!/usr/bin/env bash
# Fuzzes Pointillist's input surfaces with libFuzzer under ASan and UBSan, by
# hand (not in ctest):
#
#   deploy/fuzz.sh [SECONDS per target, default 60] [TARGET ...]
#
# Targets: fuzz_ply, fuzz_xyz, fuzz_las, fuzz_off (pointillist-preprocess's
# readers), fuzz_dataset_manifest (the manifest every role reads first; what
# parses must print and parse again the same), fuzz_dataset_files (each of a
# small dataset's binary files replaced by the input, the manifest made to
# match it, then the dataset opened and every packet read) and
# fuzz_messages (each MPI message as the roles' cores take it: tile images,
# render packets, data packets, send orders, render reports, tile tasks) and
# fuzz_service_request (every
# client message's parser and checks), and fuzz_statistical_packet (a
# statistical packet decoded whole and in two steps, then cut; the same bytes
# as class tables). Installs clang and libFuzzer when missing, builds them in
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
  targets=(fuzz_ply fuzz_xyz fuzz_las fuzz_off fuzz_dataset_manifest fuzz_dataset_files
    fuzz_statistical_packet fuzz_messages fuzz_service_request)

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
    pointillist-preprocess \
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
    log "the request seeds could not be written (error above): the service corpus starts empty"
}

# MPI messages as the roles send them (tests/fuzz/fuzz_messages.cpp: a kind
# byte, a two-byte header length, the header, the payload), made with the
# protocol's own Python module.
write_message_seeds() {
  local python="$out/fuzz_messages/python"
  mkdir -p "$python"
  protoc --proto_path="$POINTILLIST_ROOT/proto" --python_out="$python" pointillist.proto
  PYTHONPATH="$python" /usr/bin/python3 - "$1" <<'PY' ||
import struct, sys
import pointillist_pb2 as pb
out = sys.argv[1]
def seed(name, kind, header, payload=b""):
    body = header.SerializeToString()
    open(f"{out}/{name}", "wb").write(bytes([kind]) + struct.pack("<H", len(body)) + body + payload)
rect = pb.TileRect(x=0, y=0, width=64, height=32)
seed("tile-image", 0, pb.TileImageHeader(frame_id=0, tile_id=0, rect=rect,
     format=pb.PIXEL_FORMAT_RGBA8, render_rank=4, splats_rendered=100, render_time_us=50),
     bytes(64 * 32 * 4))
seed("tile-image-depth", 0, pb.TileImageHeader(frame_id=1, tile_id=2, rect=rect,
     format=pb.PIXEL_FORMAT_RGBA8, render_rank=5, depth=pb.DEPTH_FORMAT_EYE_FLOAT32),
     bytes(64 * 32 * 8))
# Ranges as protocol 12 sends them; the target's cells hold 110 + 38 i splats.
seed("render-packet", 1, pb.RenderPacket(frame_id=0, tile_id=1, rect=rect,
     range_top_level=[0, 2], range_offset=[0, 0], range_count=[100, 50], total_splats=150,
     need_top_level=[0, 2], need_first=[0, 0], need_count=[100, 50],
     traverse_rank=1, packet_id=7))
seed("render-packet-part", 1, pb.RenderPacket(frame_id=1, tile_id=0, rect=rect,
     range_top_level=[1], range_offset=[10], range_count=[40], total_splats=40,
     need_top_level=[1], need_first=[10], need_count=[40], traverse_rank=2, packet_id=8,
     part_index=1, part_count=2, screen_box=pb.TileRect(x=8, y=4, width=16, height=8)))
seed("data-packet", 2, pb.DataPacketHeader(byte_size=320, record_size=32, datasend_rank=3,
     parts=[pb.DataPart(top_level_cell=0, first_splat=0, splat_count=10)]), bytes(320))
seed("data-packet-parts", 2, pb.DataPacketHeader(byte_size=640, record_size=32, datasend_rank=3,
     parts=[pb.DataPart(top_level_cell=1, first_splat=0, splat_count=12),
            pb.DataPart(top_level_cell=2, first_splat=40, splat_count=8)]), bytes(640))
seed("send-order", 3, pb.SendOrder(render_rank=4, requester_rank=1, order_id=1,
     range_top_level=[0, 1, 5], range_first=[0, 0, 10], range_count=[110, 50, 285]))
seed("render-report", 4, pb.RenderReport(render_rank=4, sequence=1, workload_splats=1000,
     loaded_top_level=[0, 1], loaded_first=[0, 20], loaded_count=[110, 100],
     evicted_cells=[2], packets_done=3))
seed("tile-image-box", 0, pb.TileImageHeader(frame_id=0, tile_id=1, rect=rect,
     format=pb.PIXEL_FORMAT_RGBA8, render_rank=4, drawn_rect=pb.TileRect(x=4, y=2, width=16, height=8)),
     bytes(16 * 8 * 4))
seed("tile-image-part", 0, pb.TileImageHeader(frame_id=0, tile_id=2, rect=rect,
     format=pb.PIXEL_FORMAT_POINT_WORDS64, render_rank=5, part_index=0, part_count=2),
     bytes(64 * 32 * 8))
# The city of the target is about 0-100 on x and y, 0-30 on z.
camera = pb.Camera(eye=pb.Vec3(x=-20, y=-20, z=40), target=pb.Vec3(x=50, y=50, z=0),
                   up=pb.Vec3(x=0, y=0, z=1), fov_y_degrees=60, near_plane=0.1, far_plane=500,
                   image_width=640, image_height=360)
ahead = pb.Camera()
ahead.CopyFrom(camera)
ahead.eye.x = -10
seed("tile-task", 6, pb.TileTask(frame_id=3, tile_id=1, camera=camera,
     rect=pb.TileRect(x=128, y=64, width=128, height=96), lookahead_camera=ahead))
seed("tile-task-lod", 6, pb.TileTask(frame_id=4, tile_id=0, camera=camera,
     rect=pb.TileRect(x=0, y=0, width=640, height=360),
     frame_settings=pb.FrameSettings(lod_pixels=4)))
seed("traverse-report", 7, pb.RenderReport(render_rank=4, sequence=2, workload_splats=500,
     loaded_top_level=[0, 3], loaded_first=[0, 0], loaded_count=[40, 80], seconds_per_splat=1e-7,
     last_packet_from_traverse=[3, 0]))
PY
    log "the message seeds could not be written (error above): the message corpus starts empty"
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
    fuzz_statistical_packet)
      # The statistical packets of a small dataset built here (their class
      # indices are the dataset's, so most name classes the target's small
      # tables lack: the fuzzer finds its way from there) and its tables.
      "$build/bin/pointillist-preprocess" --generate city --points 3000 --statistical \
        -o "$out/$target/dataset" --force --quiet
      split -b 4096 -d "$out/$target/dataset/statistical.bin" "$corpus/packet-"
      cp "$out/$target/dataset/statistical-classes.bin" "$corpus/classes" ;;
    fuzz_messages) write_message_seeds "$corpus" ;;
    fuzz_dataset_files)
      # A small dataset the target copies and damages one file at a time; its
      # own files are the seeds (the first byte picks the file: the manifest's
      # order of file.* lines).
      export POINTILLIST_FUZZ_DATASET="$out/$target/dataset"
      "$build/bin/pointillist-preprocess" --generate city --points 3000 \
        -o "$POINTILLIST_FUZZ_DATASET" --force --quiet
      index=0
      while read -r name; do
        { printf "\\x$(printf %02x "$index")"; cat "$POINTILLIST_FUZZ_DATASET/$name"; } \
          >"$corpus/seed-$name"
        index=$((index + 1))
      done < <(awk '$1 ~ /^file\./ { print $3 }' "$POINTILLIST_FUZZ_DATASET/manifest.txt") ;;
  esac
  log "$target: $seconds s from $(ls "$corpus" | wc -l) inputs"
  max_len=65536
  [[ "$target" == fuzz_dataset_files ]] && max_len=262144  # a whole small points.bin
  result=ok
  if ! (cd "$out/$target" && "$build/bin/$target" "$corpus" -max_total_time="$seconds" \
      -timeout=10 -rss_limit_mb=4096 -max_len="$max_len" -print_final_stats=1 \
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
