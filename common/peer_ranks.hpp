#pragma once
// Who is who in a job: the world ranks of every role. The MPI job learns them
// at start-up; the simulator and the tests number a layout contiguously.
#include <cstddef>
#include <vector>

#include "common/job_layout.hpp"
#include "pointillist.pb.h"

namespace pointillist {

struct PeerRanks {
  int display = 0;
  std::vector<int> traverses;
  std::vector<int> datasends;
  std::vector<int> renders;

  // Display 0, then the traverse, data-send and render processes in order.
  static PeerRanks contiguous(const JobLayout& layout);

  // The ranks of a worker role (traverse, data-send or render).
  const std::vector<int>& of(v1::Role role) const;
  // The position of `rank` among the ranks of `role`; a ProtocolError naming
  // the rank and the role when it holds another role.
  std::size_t indexOf(v1::Role role, int rank) const;
  JobLayout layout() const;
};

}  // namespace pointillist
