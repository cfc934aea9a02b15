#include "preprocess/simd_targets.hpp"

#include <hwy/targets.h>

namespace pointillist::preprocess {

std::vector<std::int64_t> simdTargets() {
  return hwy::SupportedAndGeneratedTargets();
}

void forceSimdTarget(std::int64_t target) {
  hwy::SetSupportedTargetsForTest(target);
}

}  // namespace pointillist::preprocess
