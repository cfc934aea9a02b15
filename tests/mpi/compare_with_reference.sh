#!/usr/bin/env bash
# Runs a Pointillist job and the single-process reference renderer on the same
# dataset and cameras, then compares every frame pixel by pixel.
#   compare_with_reference.sh BIN_DIR DATASET LAYOUT CAMERA_PATH FRAMES SIZE MODE [RUN.SH OPTIONS...]
# Exits non-zero when any frame differs in more than $MAX_DIFFERING_PIXELS pixels
# (default 0: pixel-identical).
set -euo pipefail
bin="$1" dataset="$2" layout="$3" path="$4" frames="$5" size="$6" mode="$7"
shift 7
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
POINTILLIST_BUILD="$(dirname "$bin")" timeout --kill-after=10 240 \
  bash "$root/deploy/run.sh" --layout "$layout" --dataset "$dataset" --camera-path "$path" \
  --frames "$frames" --size "$size" --mode "$mode" --out "$work/job" --quiet "$@"
"$bin/pointillist-reference" --dataset "$dataset" --camera-path "$path" --frames "$frames" \
  --size "$size" --mode "$mode" --out "$work/reference" --compare "$work/job" \
  --max-differing-pixels "${MAX_DIFFERING_PIXELS:-0}"
