#!/usr/bin/env bash
# Runs a 1,2,1,4 job across three simulated hosts (network namespaces joined by
# veth links, deploy/netns-cluster.sh), then checks that
#   - ranks were placed on every host,
#   - the traffic between hosts crossed the links (TCP): at least MIN_CROSS_BYTES,
#   - the frames are pixel-identical to the single-process reference,
#   - a host whose link is shaped (--host-link-mbit) still takes part,
#   - nothing of the simulated cluster is left behind.
#   netns_cluster_test.sh BIN_DIR DATASET
# Exits 77 (ctest SKIP_RETURN_CODE) when this machine allows no namespaces.
set -euo pipefail
bin="$1" dataset="$2"
min_cross_bytes="${MIN_CROSS_BYTES:-1048576}"
hosts=3 layout=1,2,1,4 path=orbit frames=3 size=480x270
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1

# The timeout is below ctest's, so that the cluster script gets a TERM it can
# clean up after instead of being killed.
set +e
POINTILLIST_BUILD="$(dirname "$bin")" timeout --kill-after=20 240 \
  bash "$root/deploy/netns-cluster.sh" --hosts "$hosts" --layout "$layout" \
  --host-link-mbit 3:200 -- \
  --mpirun-arg --display-map \
  --dataset "$dataset" --camera-path "$path" --frames "$frames" --size "$size" --mode points \
  --out "$work/job" >"$work/job.log" 2>&1
code=$?
set -e
cat "$work/job.log"
if ((code == 77)); then
  echo "SKIPPED: this machine does not allow network namespaces (see the message above)"
  exit 77
fi
if ((code != 0)); then
  echo "FAIL: the job on the simulated cluster exited with code $code"
  exit 1
fi

if ! grep -q '^netns-cluster: host 3: link shaped to 200 Mbit/s each way$' "$work/job.log"; then
  echo "FAIL: host 3's link was not shaped"
  exit 1
fi

id=$(sed -nE 's/^netns-cluster: cluster ([0-9]+):.*/\1/p' "$work/job.log")
leftovers=$(ip netns list | grep -E "^pnt-$id-" || true)
if [[ -z "$id" || -n "$leftovers" ]]; then
  echo "FAIL: cluster '${id}' left namespaces behind: $leftovers"
  exit 1
fi

# --display-map prints "Data for node: ADDRESS  Num slots: S  Max slots: M  Num procs: P".
used=$(grep -cE '^ *Data for node: .*Num procs: [1-9]' "$work/job.log" || true)
if ((used != hosts)); then
  echo "FAIL: ranks ran on $used hosts, not on all $hosts"
  exit 1
fi

crossed=$(sed -nE 's/^netns-cluster: traffic total tx_bytes=([0-9]+)$/\1/p' "$work/job.log")
dataset_bytes=$(du -sb "$dataset" | cut -f1)
echo "between hosts: $crossed bytes over TCP (dataset: $dataset_bytes bytes, minimum: $min_cross_bytes)"
if [[ -z "$crossed" ]] || ((crossed < min_cross_bytes)); then
  echo "FAIL: only '${crossed}' bytes crossed the links between hosts"
  exit 1
fi

"$bin/pointillist-reference" --dataset "$dataset" --camera-path "$path" --frames "$frames" \
  --size "$size" --mode points --out "$work/reference" --compare "$work/job" \
  --min-lit-fraction 0.10 --min-splats 30000
