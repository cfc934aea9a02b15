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
  libgtest-dev libpng-dev libnanoflann-dev libcli11-dev libhwy-dev libxxhash-dev
  gnuplot-nox iproute2 procps
)

# Open MPI refuses to run as root unless told that it is intended.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1

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
