#!/usr/bin/env bash
# Runs a Pointillist job on a simulated cluster: N "hosts" on this machine, each
# a Linux network namespace joined by a veth link to a bridge, so that traffic
# between hosts really crosses TCP (as between cluster nodes), never shared memory.
#
#   deploy/netns-cluster.sh [--hosts N] [--layout D,T,S,R] [--subnet A.B.C] [--keep]
#                           [--cut-link H:AFTER:SECONDS] [--link-mbit MBIT]
#                           [--host-link-mbit H:MBIT ...] -- [RUN.SH OPTIONS]
#   deploy/netns-cluster.sh --teardown ID|all
#
# Needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN) and iproute2; exits 77 when the
# machine does not allow network namespaces. Defaults: 3 hosts, layout 1,2,1,4,
# subnet 10.213.0 (hosts at .11, .12, ...). Everything after "--" goes to
# deploy/run.sh (role options, --mpirun-arg ...). Prints each host's bytes on
# its link during the job. The namespaces are removed afterwards, also on
# failure, Ctrl-C or SIGTERM; --keep leaves them for inspection (remove them
# later with --teardown ID, or --teardown all for every cluster whose script
# is no longer running). --cut-link H:AFTER:SECONDS takes host H's link down
# AFTER seconds into the job, for SECONDS (a pulled cable, a switch reboot).
# --link-mbit MBIT makes every host's link that fast each way (a token bucket
# on both ends of its veth, as a NIC of that speed; default: unshaped), and
# --host-link-mbit H:MBIT sets host H's alone (0: unshaped), so that a
# display can have a faster link than the render hosts. Ranks fill hosts in
# order: with --hosts 8 and layout 1,2,1,4, host 1 holds the display and
# hosts 5-8 the render processes.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"

readonly EXIT_UNSUPPORTED=77 # ctest SKIP_RETURN_CODE: no namespaces on this machine
hosts=3
layout="1,2,1,4"
subnet="10.213.0"
keep=0
teardown_id=""
cut_link=""
link_mbit=0
declare -A host_mbit
run_args=()
usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }
say() { printf 'netns-cluster: %s\n' "$*" >&2; }
while (($#)); do
  case "$1" in
    --hosts) hosts="$2"; shift 2 ;;
    --layout) layout="$2"; shift 2 ;;
    --subnet) subnet="$2"; shift 2 ;;
    --keep) keep=1; shift ;;
    --cut-link) cut_link="$2"; shift 2 ;;
    --link-mbit) link_mbit="$2"; shift 2 ;;
    --host-link-mbit)
      if ! [[ "$2" =~ ^[0-9]+:[0-9]+$ ]]; then
        say "--host-link-mbit $2: expected HOST:MBIT, two whole numbers"
        exit 2
      fi
      host_mbit[${2%%:*}]="${2#*:}"
      shift 2
      ;;
    --teardown) teardown_id="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; run_args=("$@"); break ;;
    *) say "unknown option '$1' (options for run.sh go after --)"; usage >&2; exit 2 ;;
  esac
done

# Layout of cluster ID (the pid of the script that made it, so that concurrent
# clusters never collide and leftovers can be traced to their owner):
#   pnt-ID-sw  the "switch": bridge br0 at SUBNET.1, and mpirun
#   pnt-ID-hN  host N: eth0 at SUBNET.(10+N), the other end of the veth pair
#              being port hN of br0
# Nothing is added to the root namespace (no interface, route, firewall rule
# or listening socket), so the cluster cannot reach or shadow any real network,
# and the machine's own firewall does not see its traffic.
switch_ns() { echo "pnt-$1-sw"; }
host_ns() { echo "pnt-$1-h$2"; }
workdir_prefix() { echo "${TMPDIR:-/tmp}/pointillist-netns-$1."; }
cluster_namespaces() {
  ip netns list 2>/dev/null | awk '{ print $1 }' | grep -E "^pnt-$1-(sw|h[0-9]+)$" || true
}
namespace_pids() { local ns; for ns in "$@"; do ip netns pids "$ns" 2>/dev/null || true; done; }

# Removes everything of cluster ID: the processes left in its namespaces
# (mpirun, orted and ranks of its job: nothing else runs in there), its links,
# its namespaces and its work directory. Safe on partial set-ups and repeated.
teardown() {
  local id="$1" namespaces pids link i
  mapfile -t namespaces < <(cluster_namespaces "$id")
  ((${#namespaces[@]})) || { rm -rf "$(workdir_prefix "$id")"*; return 0; }
  mapfile -t pids < <(namespace_pids "${namespaces[@]}")
  if ((${#pids[@]})); then
    kill -TERM "${pids[@]}" 2>/dev/null || true
    for ((i = 0; i < 50; i++)); do
      mapfile -t pids < <(namespace_pids "${namespaces[@]}")
      ((${#pids[@]})) || break
      sleep 0.1
    done
    if ((${#pids[@]})); then kill -KILL "${pids[@]}" 2>/dev/null || true; fi
  fi
  # Deleting a namespace frees its interfaces later, asynchronously; deleting
  # the switch's links first removes every veth pair (both ends) at once.
  if ip netns list | awk '{ print $1 }' | grep -qxF "$(switch_ns "$id")"; then
    for link in $(ip -n "$(switch_ns "$id")" -o link show | awk -F': ' '{ sub(/@.*/, "", $2); print $2 }' |
      grep -E '^(h[0-9]+|br0)$'); do
      ip -n "$(switch_ns "$id")" link del "$link" 2>/dev/null || true
    done
  fi
  for ns in "${namespaces[@]}"; do
    ip netns del "$ns" 2>/dev/null || true
  done
  rm -rf "$(workdir_prefix "$id")"*
}

if [[ -n "$teardown_id" ]]; then
  if [[ "$teardown_id" == all ]]; then
    # Every cluster whose owning script is gone (crashed, killed, or --keep).
    for id in $(ip netns list 2>/dev/null | awk '{ print $1 }' |
      sed -nE 's/^pnt-([0-9]+)-(sw|h[0-9]+)$/\1/p' | sort -u); do
      if [[ -r /proc/$id/cmdline ]] && tr '\0' ' ' <"/proc/$id/cmdline" | grep -q netns-cluster; then
        say "cluster $id is still running (pid $id); left alone"
      else
        say "removing cluster $id"
        teardown "$id"
      fi
    done
  elif [[ "$teardown_id" =~ ^[0-9]+$ ]]; then
    teardown "$teardown_id"
  else
    say "--teardown wants a cluster id (the number in pnt-ID-hN) or 'all'"
    exit 2
  fi
  exit 0
fi

if ! [[ "$hosts" =~ ^[0-9]+$ ]] || ((hosts < 1 || hosts > 200)); then
  say "--hosts '$hosts' is not a number from 1 to 200"
  exit 2
fi
if ! [[ "$link_mbit" =~ ^[0-9]+$ ]]; then
  say "--link-mbit '$link_mbit' is not a whole number of Mbit/s"
  exit 2
fi
for h in "${!host_mbit[@]}"; do
  if ((h < 1 || h > hosts)); then
    say "--host-link-mbit $h:${host_mbit[$h]}: host $h is not one of 1..$hosts"
    exit 2
  fi
done
if ! [[ "$layout" =~ ^[0-9]+,[0-9]+,[0-9]+,[0-9]+$ ]]; then
  say "--layout '$layout' is not D,T,S,R (four counts)"
  exit 2
fi
if ! [[ "$subnet" =~ ^[0-9]{1,3}\.[0-9]{1,3}\.[0-9]{1,3}$ ]]; then
  say "--subnet '$subnet' is not the first three numbers of a /24 (e.g. 10.213.0)"
  exit 2
fi
if ! command -v ip >/dev/null || ! command -v unshare >/dev/null; then
  say "cannot simulate hosts: 'ip' (iproute2) and 'unshare' (util-linux) are needed"
  exit "$EXIT_UNSUPPORTED"
fi
if [[ $(id -u) -ne 0 ]]; then
  say "cannot simulate hosts: creating network namespaces needs root (CAP_SYS_ADMIN, CAP_NET_ADMIN)"
  exit "$EXIT_UNSUPPORTED"
fi

id=$$
sw=$(switch_ns "$id")
cidr="$subnet.0/24"
workdir=""
job_pid=""
cut_pid=""

# Stops the job if it still runs, then removes the cluster (unless --keep).
on_exit() {
  local code=$?
  trap - EXIT INT TERM HUP
  set +e
  [[ -n "$cut_pid" ]] && kill "$cut_pid" 2>/dev/null
  if [[ -n "$job_pid" ]] && kill -0 "$job_pid" 2>/dev/null; then
    say "stopping the job (run.sh pid $job_pid and its mpirun)"
    pkill -TERM -P "$job_pid" 2>/dev/null
    kill -TERM "$job_pid" 2>/dev/null
    for ((i = 0; i < 100; i++)); do kill -0 "$job_pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$job_pid" 2>/dev/null
    wait "$job_pid" 2>/dev/null
  fi
  if ((keep)) && [[ -n "$workdir" ]]; then
    say "kept: namespaces $(cluster_namespaces "$id" | tr '\n' ' ')and $workdir"
    say "remove them with: $0 --teardown $id"
  else
    teardown "$id"
  fi
  exit "$code"
}
trap on_exit EXIT
# A trapped signal ends the wait for the job at once; the EXIT trap cleans up.
trap 'exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP

# The first namespace tells whether this machine allows them at all.
if ! err=$(ip netns add "$sw" 2>&1); then
  say "cannot create network namespaces here ($err); needs root with CAP_SYS_ADMIN/CAP_NET_ADMIN"
  exit "$EXIT_UNSUPPORTED"
fi
if ! err=$(ip -n "$sw" link add br0 type bridge forward_delay 0 2>&1); then
  say "cannot create a bridge here ($err)"
  exit "$EXIT_UNSUPPORTED"
fi
ip -n "$sw" link set lo up
ip -n "$sw" addr add "$subnet.1/24" dev br0
ip -n "$sw" link set br0 up

workdir=$(mktemp -d "$(workdir_prefix "$id")XXXXXX")
layout_total=$(($(tr , + <<<"$layout")))
slots=$(((layout_total + hosts - 1) / hosts)) # fills hosts in order, all get ranks
: >"$workdir/hostfile"
: >"$workdir/hosts.map"
for ((h = 1; h <= hosts; h++)); do
  ns=$(host_ns "$id" "$h")
  addr="$subnet.$((10 + h))"
  ip netns add "$ns"
  # Port hN of the bridge; its peer is created inside the host as eth0, like a NIC.
  if ! err=$(ip -n "$sw" link add "h$h" type veth peer name eth0 netns "$ns" 2>&1); then
    say "cannot create veth links here ($err)"
    exit "$EXIT_UNSUPPORTED"
  fi
  ip -n "$sw" link set "h$h" master br0 up
  ip -n "$ns" link set lo up
  ip -n "$ns" addr add "$addr/24" dev eth0
  ip -n "$ns" link set eth0 up
  mbit="${host_mbit[$h]:-$link_mbit}"
  if ((mbit > 0)); then
    # Both directions: the host's sending (its eth0) and its receiving (the
    # bridge's port towards it). The bucket holds 64 KiB, a switch's few
    # frames; a packet waits at most 200 ms before it is dropped (TCP resends).
    for end in "$ns eth0" "$sw h$h"; do
      read -r where dev <<<"$end"
      if ! err=$(ip netns exec "$where" tc qdisc add dev "$dev" root tbf rate "${mbit}mbit" \
        burst 64kb latency 200ms 2>&1); then
        say "cannot shape host $h's link here ($err); needs tc (iproute2) and sch_tbf"
        exit "$EXIT_UNSUPPORTED"
      fi
    done
    say "host $h: link shaped to $mbit Mbit/s each way"
  fi
  # Host names are the addresses: Open MPI needs no name resolution then.
  echo "$addr slots=$slots" >>"$workdir/hostfile"
  echo "$addr $ns" >>"$workdir/hosts.map"
done
say "cluster $id: $hosts hosts in $cidr, bridge at $subnet.1 in $sw, $slots slots each"
sed 's/^/netns-cluster:   /' "$workdir/hosts.map" >&2

# mpirun runs in the switch namespace and starts one orted per host through
# the agent, which enters the host's namespace (as ssh would log in); the
# daemons call back to mpirun at the bridge address. Ranks talk over TCP only
# (ob1 + the tcp BTL; shared memory and other PMLs, which would bypass the
# links, are off), on the cluster subnet only. Every namespace shares this
# machine's cores, so nothing is bound.
# shellcheck disable=SC2054 # the commas belong to MCA values
mpirun_args=(
  --mca plm_rsh_agent "$here/netns-agent.sh"
  --mca plm_rsh_no_tree_spawn 1
  --mca pml ob1
  --mca btl self,tcp
  --mca btl_tcp_if_include "$cidr"
  --mca oob_tcp_if_include "$cidr"
  --bind-to none
)
launch=(ip netns exec "$sw" bash "$here/run.sh" --layout "$layout" --hostfile "$workdir/hostfile")
for arg in "${mpirun_args[@]}"; do
  launch+=(--mpirun-arg "$arg")
done
launch+=("${run_args[@]}")

# Link counters before the job: what the set-up itself sent is not counted.
link_bytes() { ip netns exec "$(host_ns "$id" "$1")" cat "/sys/class/net/eth0/statistics/$2_bytes"; }
declare -A before
for ((h = 1; h <= hosts; h++)); do
  before[$h,rx]=$(link_bytes "$h" rx)
  before[$h,tx]=$(link_bytes "$h" tx)
done

# In the background, so that a signal interrupts the wait and the traps run at
# once, whatever the job does. (ip netns exec execs run.sh: same pid, and
# mpirun is its child.)
POINTILLIST_NETNS_MAP="$workdir/hosts.map" "${launch[@]}" &
job_pid=$!
if [[ -n "$cut_link" ]]; then
  IFS=: read -r cut_host cut_after cut_seconds <<<"$cut_link"
  if ! [[ "$cut_host" =~ ^[0-9]+$ ]] || ((cut_host < 1 || cut_host > hosts)); then
    say "--cut-link $cut_link: host '$cut_host' is not one of 1..$hosts"
    exit 2
  fi
  (
    sleep "$cut_after"
    ip -n "$sw" link set "h$cut_host" down
    say "link of host $cut_host ($subnet.$((10 + cut_host))) cut for $cut_seconds s"
    sleep "$cut_seconds"
    ip -n "$sw" link set "h$cut_host" up
    say "link of host $cut_host restored"
  ) &
  cut_pid=$!
fi
set +e
wait "$job_pid"
job_code=$?
set -e
job_pid=""

# Bytes each host sent and received on its link during the job: all of it
# crossed TCP between namespaces (ranks on the same host talk over their own
# namespace's loopback, which is not counted here).
total=0
for ((h = 1; h <= hosts; h++)); do
  rx=$(($(link_bytes "$h" rx) - before[$h,rx]))
  tx=$(($(link_bytes "$h" tx) - before[$h,tx]))
  total=$((total + tx))
  echo "netns-cluster: traffic $(host_ns "$id" "$h") $subnet.$((10 + h)) rx_bytes=$rx tx_bytes=$tx"
done
echo "netns-cluster: traffic total tx_bytes=$total"

if ((job_code != 0)); then
  say "the job failed (exit code $job_code)"
  # 77 is reserved for "no namespaces here", so that tests do not skip a failure.
  ((job_code == EXIT_UNSUPPORTED)) && job_code=1
  exit "$job_code"
fi
