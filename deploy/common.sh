# Shared by the deploy scripts: paths, package installation, build.
# shellcheck shell=bash
POINTILLIST_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
POINTILLIST_BUILD="${POINTILLIST_BUILD:-$POINTILLIST_ROOT/build}"
POINTILLIST_BIN="$POINTILLIST_BUILD/bin"

# Debian packages the build, the tests and the benchmarks need.
POINTILLIST_PACKAGES=(
  build-essential cmake pkg-config
  openmpi-bin libopenmpi-dev
  libosmesa6-dev libglm-dev libfftw3-dev
  libzmq3-dev cppzmq-dev libprotobuf-dev protobuf-compiler libturbojpeg0-dev
  python3-zmq python3-protobuf python3-numpy
  libboost-dev chromium python3-websocket
  libgtest-dev libpng-dev libnanoflann-dev libcli11-dev libhwy-dev libxxhash-dev libzstd-dev
  gnuplot-nox iproute2 procps
)

# Open MPI refuses to run as root unless told that it is intended.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1

# glibc's heap for the role processes: freed memory kept for reuse instead of
# handed back and faulted in again. Render processes receive and store
# hundreds of MiB; on a VM a page fault on fresh memory costs more than the
# copy into it. Transparent huge pages cost the job more than they save: a
# render's cache grows into fresh memory, and zeroing fresh 2 MiB pages took
# half of the render processes' CPU on the bunny orbit (measured with perf,
# 2026-11-26: render CPU per frame 67 -> 35 core-ms without them). The
# reference, one process that reads the whole dataset once and then draws
# from it, keeps them (5-9 % more frames/s). Set POINTILLIST_MALLOC_TUNING=0
# to run with glibc's defaults.
POINTILLIST_MALLOC_TUNABLES="glibc.malloc.mmap_threshold=33554432"
POINTILLIST_MALLOC_TUNABLES+=":glibc.malloc.trim_threshold=1073741824:glibc.malloc.top_pad=67108864"
use_malloc_tuning() {
  [[ "${POINTILLIST_MALLOC_TUNING:-1}" == 0 ]] && return 0
  [[ "${GLIBC_TUNABLES:-}" == *"$POINTILLIST_MALLOC_TUNABLES"* ]] && return 0
  export GLIBC_TUNABLES="${GLIBC_TUNABLES:+$GLIBC_TUNABLES:}$POINTILLIST_MALLOC_TUNABLES"
}
# GLIBC_TUNABLES for pointillist-reference: the job's, plus huge pages.
reference_malloc_tunables() {
  if [[ "${POINTILLIST_MALLOC_TUNING:-1}" == 0 ]]; then
    echo "${GLIBC_TUNABLES:-}"
  else
    echo "glibc.malloc.hugetlb=1:$POINTILLIST_MALLOC_TUNABLES"
  fi
}

# True when one process may read another's memory with process_vm_readv (what
# Open MPI's CMA single copy needs): no Yama restriction, and a probe of a
# forked child passes (container seccomp filters may forbid the call).
# Whether a process may open another's memory file through /proc/PID/fd (as a
# render process opens a data-send's shared packets, common/shared_packets.hpp):
# a child holds a memfd, this process reads it by that path.
shared_packets_allowed() {
  python3 - <<'PROBE' 2>/dev/null
import os, signal, sys, time
fd = os.memfd_create("pointillist-probe")
os.write(fd, b"pointillist")
ready, told = os.pipe()
child = os.fork()
if child == 0:
    os.write(told, b"x")
    time.sleep(30)
    os._exit(0)
os.read(ready, 1)
os.close(fd)  # the child's descriptor alone keeps the file
try:
    with open(f"/proc/{child}/fd/{fd}", "rb") as memory:
        found = memory.read(11) == b"pointillist"
except OSError:
    found = False
os.kill(child, signal.SIGKILL)
os.waitpid(child, 0)
sys.exit(0 if found else 1)
PROBE
}
cma_allowed() {
  local scope=/proc/sys/kernel/yama/ptrace_scope
  [[ -r "$scope" && "$(cat "$scope")" != 0 ]] && return 1
  python3 - <<'PROBE' 2>/dev/null
import ctypes, os, signal, sys, time
libc = ctypes.CDLL(None, use_errno=True)
class IoVec(ctypes.Structure):
    _fields_ = [("base", ctypes.c_void_p), ("length", ctypes.c_size_t)]
source = ctypes.create_string_buffer(b"pointillist", 16)
child = os.fork()
if child == 0:
    time.sleep(30)
    os._exit(0)
target = ctypes.create_string_buffer(16)
local = IoVec(ctypes.cast(target, ctypes.c_void_p), 16)
remote = IoVec(ctypes.cast(source, ctypes.c_void_p), 16)
read = libc.process_vm_readv(child, ctypes.byref(local), 1, ctypes.byref(remote), 1, 0)
os.kill(child, signal.SIGKILL)
os.waitpid(child, 0)
sys.exit(0 if read == 16 and target.value == b"pointillist" else 1)
PROBE
}

log() { printf '[pointillist] %s\n' "$*" >&2; }

# Installs whatever is missing; does nothing (and needs no network) otherwise.
install_packages() {
  local missing=()
  local pkg
  for pkg in "${POINTILLIST_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'install ok installed' || missing+=("$pkg")
  done
  if ((${#missing[@]} == 0)); then
    return 0
  fi
  log "installing Debian packages: ${missing[*]}"
  local sudo=()
  if [[ $(id -u) -ne 0 ]]; then
    sudo=(sudo)
  fi
  "${sudo[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

# Configures (once) and builds everything into $POINTILLIST_BUILD.
build_all() {
  local build_type="${POINTILLIST_BUILD_TYPE:-RelWithDebInfo}"
  if [[ ! -f "$POINTILLIST_BUILD/CMakeCache.txt" ]]; then
    log "configuring ($build_type) in $POINTILLIST_BUILD"
    cmake -S "$POINTILLIST_ROOT" -B "$POINTILLIST_BUILD" -DCMAKE_BUILD_TYPE="$build_type" >/dev/null
  fi
  log "building (log: $POINTILLIST_BUILD/build.log)"
  if ! cmake --build "$POINTILLIST_BUILD" -j "$(nproc)" >"$POINTILLIST_BUILD/build.log" 2>&1; then
    tail -n 60 "$POINTILLIST_BUILD/build.log" >&2
    log "build failed; full log in $POINTILLIST_BUILD/build.log"
    return 1
  fi
}

# Configures DIR as a Release build without tests unless it is configured
# already, then builds it (the benchmarks' build).
build_release() {
  local build="$1"
  if [[ ! -f "$build/CMakeCache.txt" ]]; then
    log "configuring a Release build in $build"
    cmake -S "$POINTILLIST_ROOT" -B "$build" -DCMAKE_BUILD_TYPE=Release \
      -DPOINTILLIST_BUILD_TESTS=OFF >/dev/null
  fi
  log "building $build"
  cmake --build "$build" -j "$(nproc)" >/dev/null
}

# libcgal-demo's data (real scans and meshes), fetched once into .cache/.
POINTILLIST_CGAL_DATA="$POINTILLIST_ROOT/.cache/cgal-data/data"
ensure_cgal_data() {
  [[ -d "$POINTILLIST_CGAL_DATA" ]] || bash "$POINTILLIST_ROOT/deploy/fetch-test-data.sh" >&2
}

# The seed benchmarks' scenes (bench-instanced, bench-statistical) as
# pointillist-preprocess input arguments: the built-in city, CGAL's
# building.ply scan, the bunny mesh sampled to 2 M points. Fails for another
# name.
bench_scene_input() {
  case "$1" in
    city) echo "--generate city" ;;
    building) echo "$POINTILLIST_CGAL_DATA/points_3/building.ply" ;;
    bunny) echo "$POINTILLIST_CGAL_DATA/meshes/bunny00.off --points 2000000" ;;
    *) return 1 ;;
  esac
}

# Prints the dataset folder of a benchmark scene, made first when it is not
# there in this build's format: bunny-10M (Debian's bunny00.off from
# libcgal-demo sampled to 10 M points) or city (the built-in city, 2 M points).
scene_dataset() {
  local dir
  case "$1" in
    bunny-10M)
      dir="$POINTILLIST_ROOT/datasets/bunny-10M"
      if ! "$POINTILLIST_BIN/pointillist-preprocess" --check "$dir" >/dev/null 2>&1; then
        bash "$POINTILLIST_ROOT/deploy/fetch-test-data.sh" >&2
        log "sampling bunny00.off to 10 M points into $dir"
        "$POINTILLIST_BIN/pointillist-preprocess" \
          "$POINTILLIST_ROOT/.cache/cgal-data/data/meshes/bunny00.off" --points 10000000 \
          -o "$dir" --force --quiet >&2
      fi ;;
    city)
      dir="$POINTILLIST_ROOT/datasets/city-2000000"
      ensure_city_dataset "$dir" 2000000 >&2 ;;
    *) echo "unknown scene '$1' (bunny-10M or city)" >&2; return 2 ;;
  esac
  echo "$dir"
}

# Generates the built-in city scene with POINTS points into DIR unless DIR
# already holds a sound dataset of this build's format (an older format or a
# damaged one is rebuilt, saying why). Progress goes to stderr.
ensure_city_dataset() {
  local dataset="$1" points="$2" why
  if [[ -f "$dataset/manifest.txt" ]]; then
    if why=$("$POINTILLIST_BIN/pointillist-preprocess" --check "$dataset" 2>&1 >/dev/null); then
      return 0
    fi
    log "rebuilding $dataset: ${why##*: }"
  else
    log "preprocessing the built-in city scene ($points points) into $dataset"
  fi
  "$POINTILLIST_BIN/pointillist-preprocess" --generate city --points "$points" -o "$dataset" \
    --force >&2
}
