#!/usr/bin/env bash
# Runs a Pointillist job and the single-process reference renderer on the same
# dataset and cameras, then compares every frame pixel by pixel.
#   compare_with_reference.sh BIN_DIR DATASET LAYOUT CAMERA_PATH FRAMES SIZE MODE [RUN.SH OPTIONS...]
# Environment:
#   MAX_DIFFERING_PIXELS  pixels allowed to differ per frame (default 0: identical)
#   EXPECT_OUTPUT         a regex the job's output must match (e.g. re-issued tiles)
#   CACHE_CAP_MB          the render cache cap given to the job: evictions must
#                         happen and the peak cache must stay within it
#   RENDERER, UNLIT       --renderer RENDERER and (when set) --unlit, given to both
#                         the job and the reference
#   EDL                   when set, --edl (eye-dome lighting) to both; EDL_RADIUS
#                         and EDL_STRENGTH, when set, go with it
#   MIN_LIT_FRACTION      every frame, the job's and the reference's, must have at
#   MIN_SPLATS            least this share of pixels off the background and draw
#                         this many splats: two blank frames would match (required,
#                         set per scene in tests/mpi/CMakeLists.txt)
set -euo pipefail
bin="$1" dataset="$2" layout="$3" path="$4" frames="$5" size="$6" mode="$7"
shift 7
: "${MIN_LIT_FRACTION:?set the scene's floor of lit pixels}" "${MIN_SPLATS:?set the scene's floor of splats}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
extra=()
# Options the job and the reference must share: the drawing kernel and shading.
view=()
if [[ -n "${RENDERER:-}" ]]; then
  view+=(--renderer "$RENDERER")
fi
if [[ -n "${UNLIT:-}" ]]; then
  view+=(--unlit)
fi
if [[ -n "${EDL:-}" ]]; then
  view+=(--edl)
  [[ -n "${EDL_RADIUS:-}" ]] && view+=(--edl-radius "$EDL_RADIUS")
  [[ -n "${EDL_STRENGTH:-}" ]] && view+=(--edl-strength "$EDL_STRENGTH")
fi
if [[ -n "${CACHE_CAP_MB:-}" ]]; then
  extra+=(--cache-mb "$CACHE_CAP_MB")
fi
set +e
POINTILLIST_BUILD="$(dirname "$bin")" timeout --kill-after=10 240 \
  bash "$root/deploy/run.sh" --layout "$layout" --dataset "$dataset" --camera-path "$path" \
  --frames "$frames" --size "$size" --mode "$mode" --out "$work/job" "${view[@]}" "${extra[@]}" "$@" \
  >"$work/job.log" 2>&1
code=$?
set -e
cat "$work/job.log"
if ((code != 0)); then
  echo "FAIL: the job exited with code $code"
  exit 1
fi
if [[ -n "${EXPECT_OUTPUT:-}" ]] && ! grep -Eq -- "$EXPECT_OUTPUT" "$work/job.log"; then
  echo "FAIL: job output does not match /$EXPECT_OUTPUT/"
  exit 1
fi
if [[ -n "${CACHE_CAP_MB:-}" ]]; then
  line=$(grep -E '^cache: ' "$work/job.log")
  evictions=$(sed -E 's/.* ([0-9]+) evictions.*/\1/' <<<"$line")
  peak=$(sed -E 's/.*peak ([0-9.]+) MiB.*/\1/' <<<"$line")
  echo "cache cap ${CACHE_CAP_MB} MiB: $evictions evictions, peak $peak MiB"
  if ((evictions == 0)); then
    echo "FAIL: no evictions under a ${CACHE_CAP_MB} MiB cap"
    exit 1
  fi
  if ! awk -v p="$peak" -v c="$CACHE_CAP_MB" 'BEGIN{exit !(p <= c)}'; then
    echo "FAIL: peak cache $peak MiB exceeds the ${CACHE_CAP_MB} MiB cap"
    exit 1
  fi
fi
"$bin/pointillist-reference" --dataset "$dataset" --camera-path "$path" --frames "$frames" \
  --size "$size" --mode "$mode" "${view[@]}" --out "$work/reference" --compare "$work/job" \
  --max-differing-pixels "${MAX_DIFFERING_PIXELS:-0}" \
  --min-lit-fraction "$MIN_LIT_FRACTION" --min-splats "$MIN_SPLATS"
if [[ -n "${EDL:-}" ]]; then
  # Both sides could skip the pass and still agree: the job's frames must
  # differ from the reference's without it.
  plain=()
  for option in "${view[@]}"; do
    [[ "$option" == --edl ]] && break
    plain+=("$option")
  done
  "$bin/pointillist-reference" --dataset "$dataset" --camera-path "$path" --frames "$frames" \
    --size "$size" --mode "$mode" "${plain[@]}" --compare "$work/job" \
    --max-differing-pixels 100 >"$work/plain.log" 2>&1 || true
  differing=$(grep -c MISMATCH "$work/plain.log" || true)
  if ((differing != frames)); then
    cat "$work/plain.log"
    echo "FAIL: $((frames - differing)) job frame(s) with --edl are (nearly) those without it"
    exit 1
  fi
  echo "eye-dome lighting: every job frame differs from the reference without it in over 100 pixels"
fi
