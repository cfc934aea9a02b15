#!/usr/bin/env bash
# Open MPI launch agent for deploy/netns-cluster.sh: stands in for ssh, but
# "logs in" to a simulated host by entering its network namespace.
#
#   netns-agent.sh HOST COMMAND...
#
# HOST is a namespace name, or an address listed in the file named by
# $POINTILLIST_NETNS_MAP (lines "ADDRESS NAMESPACE", written by netns-cluster.sh).
# Open MPI's rsh launcher hands over the remote command as several words meant
# for a remote shell (e.g. "PATH=...; export PATH; ... orted -mca ..."), so, as
# ssh does, the words are joined with spaces and run by the login shell.
set -euo pipefail

if (($# < 2)); then
  echo "netns-agent.sh: usage: netns-agent.sh HOST COMMAND..." >&2
  exit 255 # what ssh returns when it cannot connect
fi
host="$1"
shift

ns=""
if [[ -n "${POINTILLIST_NETNS_MAP:-}" && -r "$POINTILLIST_NETNS_MAP" ]]; then
  ns=$(awk -v h="$host" '$1 == h { print $2; exit }' "$POINTILLIST_NETNS_MAP")
fi
if [[ -z "$ns" ]]; then
  ns="$host"
fi
if ! ip netns list | awk '{ print $1 }' | grep -qxF -- "$ns"; then
  echo "netns-agent.sh: no network namespace for host '$host'" >&2
  exit 255
fi

# The shell Open MPI wrote the command for: with plm_rsh_assume_same_shell
# (the default) that is the login shell of the user running mpirun.
shell=$(getent passwd "$(id -u)" | cut -d: -f7)
[[ -x "$shell" ]] || shell=/bin/sh

# A UTS namespace of its own gives each simulated host its own host name, so
# that Open MPI and the job's messages ("rank N on HOST") tell hosts apart.
# shellcheck disable=SC2016 # $1..$3 are expanded by the inner shell
exec ip netns exec "$ns" unshare --uts /bin/sh -c 'hostname "$1" && exec "$2" -c "$3"' \
  netns-agent "$ns" "$shell" "$*"
