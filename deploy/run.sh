#!/usr/bin/env bash
# Starts a Pointillist MPMD job: one display, T traverse, S data-send and R
# render processes. Options this script does not know are passed to every role.
#
#   deploy/run.sh [--layout D,T,S,R] [--hostfile FILE] [--mpirun-arg ARG]... [ROLE OPTIONS]
#
# On one machine (no --hostfile) ranks are oversubscribed and unbound, so more
# ranks than cores share them; idle ranks sleep instead of spinning.
# With --hostfile, Open MPI places ranks on the listed hosts (see deploy/README.md).
# --serve [--listen ENDPOINT] keeps the job up as a rendering service (README:
# "The rendering service"); it ends on a shutdown request, SIGINT or SIGTERM.
# mpirun runs with --enable-recovery, so a lost process does not end the job
# by itself: the display drops a lost render process and goes on, and ends
# the job with a message naming any other lost process (--no-recovery: Open
# MPI's own abort instead).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

layout="1,2,1,4"
hostfile=""
mpirun_args=()
role_args=()
dry_run=0
recovery=1
usage() { sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
while (($#)); do
  case "$1" in
    --layout) layout="$2"; shift 2 ;;
    --layout=*) layout="${1#*=}"; shift ;;
    --hostfile) hostfile="$2"; shift 2 ;;
    --hostfile=*) hostfile="${1#*=}"; shift ;;
    --mpirun-arg) mpirun_args+=("$2"); shift 2 ;;
    --dry-run) dry_run=1; shift ;;
    --no-recovery) recovery=0; shift ;;
    -h|--help) usage; exit 0 ;;
    *) role_args+=("$1"); shift ;;
  esac
done

if ! [[ "$layout" =~ ^[0-9]+,[0-9]+,[0-9]+,[0-9]+$ ]]; then
  echo "run.sh: --layout '$layout' is not D,T,S,R (four counts)" >&2
  exit 2
fi
IFS=, read -r n_display n_traverse n_datasend n_render <<<"$layout"

for exe in display traverse datasend render; do
  if [[ ! -x "$POINTILLIST_BIN/pointillist-$exe" ]]; then
    echo "run.sh: $POINTILLIST_BIN/pointillist-$exe is missing; build first (deploy/demo.sh builds)" >&2
    exit 2
  fi
done

# Shared memory moves large messages with one copy through Linux CMA
# (process_vm_readv) where ranks of one user may read each other's memory; on
# the bunny orbit that took the job from about 20-27 to 32-36 frames/s (2
# cores). Where Yama or a seccomp filter forbids it, the two-copy path stays.
# The probe only speaks for this machine, so a --hostfile launch keeps the
# two-copy path. POINTILLIST_SINGLE_COPY=none|cma decides instead.
single_copy="${POINTILLIST_SINGLE_COPY:-}"
if [[ -z "$single_copy" ]]; then
  single_copy=none
  [[ -z "$hostfile" ]] && cma_allowed && single_copy=cma
fi
# Render processes read data packets in place from a data-send process of
# their machine (common/shared_packets.hpp) where a process may open another's
# memory file through /proc/PID/fd; where this machine forbids it, packets are
# copied. The probe speaks for this machine: with nodes set up otherwise, pass
# --shared-packets off (or on) yourself.
shared_packets_given=0
for arg in "${role_args[@]}"; do
  [[ "$arg" == --shared-packets || "$arg" == --shared-packets=* ]] && shared_packets_given=1
done
if ((!shared_packets_given)) && ! shared_packets_allowed; then
  echo "run.sh: processes may not open each other's memory files here; data packets are copied (--shared-packets off)" >&2
  role_args+=(--shared-packets off)
fi
launch=(mpirun --mca btl_vader_single_copy_mechanism "$single_copy")
((recovery)) && launch+=(--enable-recovery)
if [[ -n "$hostfile" ]]; then
  [[ -r "$hostfile" ]] || { echo "run.sh: cannot read hostfile '$hostfile'" >&2; exit 2; }
  launch+=(--hostfile "$hostfile")
else
  launch+=(--oversubscribe --bind-to none)
fi
use_malloc_tuning
[[ -n "${GLIBC_TUNABLES:-}" ]] && launch+=(-x GLIBC_TUNABLES)
launch+=("${mpirun_args[@]}")

common_args=(--expect-layout "$layout" "${role_args[@]}")
launch+=(-np "$n_display" "$POINTILLIST_BIN/pointillist-display" "${common_args[@]}")
launch+=(: -np "$n_traverse" "$POINTILLIST_BIN/pointillist-traverse" "${common_args[@]}")
launch+=(: -np "$n_datasend" "$POINTILLIST_BIN/pointillist-datasend" "${common_args[@]}")
launch+=(: -np "$n_render" "$POINTILLIST_BIN/pointillist-render" "${common_args[@]}")

if ((dry_run)); then
  printf '%q ' "${launch[@]}"
  echo
  exit 0
fi
serving=0
for arg in "${role_args[@]}"; do [[ "$arg" == --serve ]] && serving=1; done

# With --enable-recovery mpirun exits 0 whatever its processes return, so the
# job's outcome is read from stderr: every role reports a fatal error as
# "pointillist-ROLE rank N: KIND: MESSAGE" (the display's last word after a
# lost process is one), and MPI_Abort leaves Open MPI's own banner.
failures=$(mktemp)
trap 'rm -f "$failures"' EXIT
watch_errors() {
  local line
  trap '' INT TERM  # a terminal's Ctrl-C must not cut the job's stderr
  while IFS= read -r line; do
    printf '%s\n' "$line" >&2
    if [[ "$line" =~ ^pointillist-[a-z]+(\ rank\ [0-9]+)?:\  || "$line" == "MPI_ABORT was invoked"* ]]; then
      printf '%s\n' "$line" >>"$failures"
    fi
  done
}
# The exit status: mpirun's, or 4 (a lost process) / 1 when a process failed.
job_status() {
  local code="$1"
  if ((code == 0)) && [[ -s "$failures" ]]; then
    if grep -q ": lost process: " "$failures"; then code=4; else code=1; fi
  fi
  echo "$code"
}
if ((!serving)); then
  code=0
  "${launch[@]}" 2> >(watch_errors) || code=$?
  wait  # and the last process substitution: the watcher has written every line
  exit "$(job_status "$code")"
fi

# Serve mode: SIGINT (a terminal's Ctrl-C) or SIGTERM (a batch scheduler) to
# this script becomes SIGINT to the display, which finishes the frames out and
# shuts every process down cleanly. mpirun runs in a session of its own so a
# terminal's Ctrl-C does not reach it: Open MPI would kill the ranks.
setsid "${launch[@]}" 2> >(watch_errors) &
mpirun_pid=$!
stop_service() {
  local display
  display=$(pgrep -s "$mpirun_pid" -f "^[^ ]*/pointillist-display( |$)" || true)
  if [[ -n "$display" ]]; then
    echo "run.sh: stopping the service (SIGINT to the display)" >&2
    kill -INT $display 2>/dev/null || true
  else
    # The display runs on another host (--hostfile): Open MPI ends the job.
    kill -TERM "$mpirun_pid" 2>/dev/null || true
  fi
}
trap stop_service INT TERM
code=0
while kill -0 "$mpirun_pid" 2>/dev/null; do
  code=0
  wait "$mpirun_pid" || code=$?
done
# A signal may have cut the last wait short: the status is still to collect.
last=0
wait "$mpirun_pid" 2>/dev/null || last=$?
if ((last != 127)); then code=$last; fi
wait  # the watcher has written every line
exit "$(job_status "$code")"
