#pragma once
// Render processes that share a machine's cores. Seed 003's cost function
// takes each render process to have its own node: a packet queued behind
// other work waits for it, so spreading tiles over more render processes buys
// parallelism worth some data moved. When processes outnumber a machine's
// cores, a render process with a shorter queue does not draw any sooner (the
// cores are busy with the others), while every byte moved costs CPU that all
// of them share. The traverse then weighs a render process's queue by the
// share of a core each process of its machine has (docs/scheduling.md §11).
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "pointillist.pb.h"

namespace pointillist {

struct ProcessPlacement {
  int rank = 0;
  v1::Role role = v1::ROLE_UNSPECIFIED;
  std::string host;
  std::vector<std::uint32_t> cpus;  // processors the process may run on
};

// Per render process, in ascending rank: the processors its machine's job
// processes may run on (the union of their affinities) over the number of job
// processes on that machine, at most 1. A process that names no processor
// counts as having one of its own.
std::vector<float> renderCoreShares(std::span<const ProcessPlacement> processes);

// The processors the calling process may run on (its affinity).
std::vector<std::uint32_t> allowedCpus();

}  // namespace pointillist
