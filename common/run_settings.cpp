#include "common/run_settings.hpp"

#include "common/errors.hpp"

namespace pointillist {

v1::CostModel parseCostModel(const std::string& name) {
  if (name == "paper") return v1::COST_MODEL_PAPER;
  if (name == "overlap") return v1::COST_MODEL_OVERLAP;
  throw UsageError("cost model '" + name + "' is not one of: paper, overlap");
}

const char* costModelName(v1::CostModel model) {
  return model == v1::COST_MODEL_OVERLAP ? "overlap" : "paper";
}

}  // namespace pointillist
