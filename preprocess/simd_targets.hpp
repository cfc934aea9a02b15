#pragma once
// For tests of the preprocess's SIMD kernels (Highway, run-time dispatch):
// the targets this binary has and the machine runs, and one of them forced for
// every later dispatch, so each target's results can be checked against the
// scalar code's.
#include <cstdint>
#include <vector>

namespace pointillist::preprocess {

std::vector<std::int64_t> simdTargets();
void forceSimdTarget(std::int64_t target);  // 0: the best again

}  // namespace pointillist::preprocess
