#!/usr/bin/env bash
# The main job on the built-in default: installs what is missing, builds,
# preprocesses the built-in "city" scene and renders an orbit around it with a
# 1,2,1,4 job (display, 2 traverse, 1 data-send, 4 render processes) on this
# machine. Frames and statistics land in out/demo/.
#   deploy/demo.sh [--points N] [RUN.SH OPTIONS...]   e.g. --layout 1,2,2,8 --frames 48
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
points=2000000
args=()
while (($#)); do
  case "$1" in
    --points) points="$2"; shift 2 ;;
    *) args+=("$1"); shift ;;
  esac
done
install_packages
build_all
dataset="$POINTILLIST_ROOT/datasets/city-$points"
ensure_city_dataset "$dataset" "$points"
out="$POINTILLIST_ROOT/out/demo"
log "rendering an orbit with layout 1,2,1,4 into $out"
bash "$POINTILLIST_ROOT/deploy/run.sh" --layout 1,2,1,4 --dataset "$dataset" \
  --camera-path orbit --frames 24 --size 1280x720 --out "$out" "${args[@]}"
log "frames: $out/frame_*.png, statistics: $out/stats.json"
