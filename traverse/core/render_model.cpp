#include "traverse/core/render_model.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/errors.hpp"
#include "common/octree_cell.hpp"
#include "common/splat.hpp"

namespace pointillist::traverse {

v1::CostModel costModelMessage(CostModel model) {
  return model == CostModel::Overlap ? v1::COST_MODEL_OVERLAP : v1::COST_MODEL_PAPER;
}

CostModel costModelOf(v1::CostModel model) {
  return model == v1::COST_MODEL_OVERLAP ? CostModel::Overlap : CostModel::Paper;
}

RenderModel::RenderModel(std::size_t renderCount, CostModel costModel)
    : renders_(renderCount), costModel_(costModel) {
  if (renderCount == 0) throw UsageError("a render model needs at least one render process");
}

void RenderModel::setCoreShares(std::span<const float> shares) {
  for (std::size_t render = 0; render < renders_.size(); ++render) {
    const double share = render < shares.size() ? static_cast<double>(shares[render]) : 1.0;
    // A share outside (0, 1] is not one a display sends: take a node each.
    renders_[render].coreShare = share > 0.0 && share <= 1.0 ? share : 1.0;
  }
}

std::uint64_t RenderModel::workload(std::size_t render) const {
  const RenderState& state = renders_.at(render);
  std::uint64_t total = state.reportedWorkload;
  for (const auto& [id, splats] : state.unreported) total += splats;
  return total;
}

const RenderModel::Holding* RenderModel::holding(std::uint32_t cell, std::size_t render) const {
  if (cell >= holders_.size()) return nullptr;
  for (const Holding& held : holders_[cell]) {
    if (held.render == render) return &held;
  }
  return nullptr;
}

RenderModel::Holding& RenderModel::holdingFor(std::uint32_t cell, std::size_t render) {
  if (cell >= holders_.size()) holders_.resize(std::size_t{cell} + 1);
  for (Holding& held : holders_[cell]) {
    if (held.render == render) return held;
  }
  Holding& added = holders_[cell].emplace_back();
  added.render = static_cast<std::uint32_t>(render);
  return added;
}

void RenderModel::dropHolding(std::uint32_t cell, std::size_t render) {
  if (cell >= holders_.size()) return;
  std::erase_if(holders_[cell], [&](const Holding& held) {
    if (held.render != render) return false;
    if (held.confirmed) --renders_[render].confirmedCells;
    return true;
  });
}

std::uint64_t RenderModel::heldSplats(std::size_t render, std::uint32_t cell) const {
  (void)renders_.at(render);
  const Holding* held = holding(cell, render);
  return held != nullptr ? held->spans.splats() : 0;
}

template <class Gap>
void RenderModel::forEachMissing(std::size_t render, std::span<const CellRange> needs,
                                 Gap&& gap) const {
  static const SpanSet kNone;
  forEachCellBlock(needs, [&](std::uint32_t cell, std::span<const CellRange> block) {
    const Holding* held = holding(cell, render);
    const SpanSet& spans = held != nullptr ? held->spans : kNone;
    for (const CellRange& need : block) {
      spans.forEachGap(need.first, static_cast<std::uint32_t>(need.end()),
                       [&](std::uint32_t begin, std::uint32_t end) { gap(cell, begin, end); });
    }
  });
}

std::uint64_t RenderModel::missingSplats(std::size_t render,
                                         std::span<const CellRange> needs) const {
  (void)renders_.at(render);
  std::uint64_t splats = 0;
  forEachMissing(render, needs, [&](std::uint32_t, std::uint32_t begin, std::uint32_t end) {
    splats += end - begin;
  });
  return splats;
}

std::uint64_t RenderModel::splatsHeldElsewhere(std::size_t render,
                                               std::span<const CellRange> ranges) const {
  // The other renders' holdings of a cell joined once for all its ranges
  // (ranges come sorted by cell).
  std::uint64_t splats = 0;
  std::uint32_t joinedCell = kNoIndex;
  SpanSet others;
  for (const CellRange& range : ranges) {
    if (range.cell >= holders_.size()) continue;
    if (range.cell != joinedCell) {
      joinedCell = range.cell;
      others = {};
      for (const Holding& held : holders_[range.cell]) {
        if (held.render != render) others.add(held.spans);
      }
    }
    if (others.empty()) continue;
    splats += range.count - others.uncovered(range.first, static_cast<std::uint32_t>(range.end()));
  }
  return splats;
}

std::size_t RenderModel::cachedCellCount(std::size_t render) const {
  return renders_.at(render).confirmedCells;
}

namespace {

// Mean of the measured values (> 0), or `fallback` when none is.
template <class Get>
double meanMeasured(const auto& renders, Get get, double fallback) {
  double sum = 0.0;
  std::size_t measured = 0;
  for (const auto& state : renders) {
    if (get(state) > 0.0) {
      sum += get(state);
      ++measured;
    }
  }
  return measured > 0 ? sum / static_cast<double>(measured) : fallback;
}

}  // namespace

double RenderModel::secondsPerSplat() const {
  return meanMeasured(
      renders_, [](const RenderState& s) { return s.secondsPerSplat; }, kDefaultSecondsPerSplat);
}

double RenderModel::secondsPerByte() const {
  return meanMeasured(
      renders_, [](const RenderState& s) { return s.secondsPerByte; }, kDefaultSecondsPerByte);
}

// A process with nothing queued counts at the mean: its own figure may date
// from a moment of contention that has passed, and only work it is given can
// measure it again (otherwise one slow sample would starve it for good).
double RenderModel::secondsPerSplat(std::size_t render) const {
  const double own = renders_.at(render).secondsPerSplat;
  return own > 0.0 && workload(render) > 0 ? own : secondsPerSplat();
}

double RenderModel::secondsPerByte(std::size_t render) const {
  const double own = renders_.at(render).secondsPerByte;
  return own > 0.0 && workload(render) > 0 ? own : secondsPerByte();
}

double RenderModel::cost(std::size_t render, std::span<const CellRange> needs, std::uint64_t splats,
                         std::uint64_t* missingBytes) const {
  const std::uint64_t missing = missingSplats(render, needs) * sizeof(Splat);
  if (missingBytes != nullptr) *missingBytes = missing;
  return costWith(render, missing, splats);
}

double RenderModel::costWith(std::size_t render, std::uint64_t missing,
                             std::uint64_t splats) const {
  // The packet's own splats cost the same everywhere; they are included so the
  // figure reads as the expected completion time on that render.
  const double splatSeconds = secondsPerSplat(render);
  const double queued =
      static_cast<double>(workload(render)) * splatSeconds * renders_[render].coreShare;
  const double transfer = static_cast<double>(missing) * secondsPerByte(render);
  const double own = static_cast<double>(splats) * splatSeconds;
  if (costModel_ == CostModel::Paper) return queued + transfer + own;
  return std::max(queued, transfer) + own;
}

bool RenderModel::suspectedStalled(std::size_t render, Clock::time_point now) const {
  const RenderState& state = renders_.at(render);
  if (!state.waitingSince) return false;
  const double expected = static_cast<double>(workload(render)) * secondsPerSplat(render);
  const double waited = std::chrono::duration<double>(now - *state.waitingSince).count();
  return waited > std::max(1.0, 4.0 * expected);
}

double RenderModel::leastQueuedSeconds(Clock::time_point now) const {
  double least = std::numeric_limits<double>::infinity();
  for (std::size_t render = 0; render < renders_.size(); ++render) {
    if (renders_[render].retired || suspectedStalled(render, now)) continue;
    least = std::min(least, queuedSeconds(render));
  }
  return least;
}

bool RenderModel::canTakePart(std::size_t render, double least, double slack,
                              Clock::time_point now) const {
  const RenderState& state = renders_.at(render);
  if (state.retired || suspectedStalled(render, now)) return false;
  const double queued = queuedSeconds(render);
  if (queued > least + slack) return false;
  // Finishing nothing for twice its queue's time and the slack: do not count
  // on it for work meant to run at once (long before it is suspected stalled).
  if (state.waitingSince &&
      std::chrono::duration<double>(now - *state.waitingSince).count() > 2.0 * queued + slack) {
    return false;
  }
  return true;
}

std::size_t RenderModel::rendersForParts(double slack, Clock::time_point now) const {
  const double least = leastQueuedSeconds(now);
  std::size_t count = 0;
  for (std::size_t render = 0; render < renders_.size(); ++render) {
    if (canTakePart(render, least, slack, now)) ++count;
  }
  return count;
}

std::optional<RenderChoice> RenderModel::chooseAmong(
    std::span<const CellRange> needs, std::uint64_t splats, Clock::time_point now,
    const std::function<bool(std::size_t)>& candidate) const {
  const std::size_t count = renders_.size();
  if (liveCount() == 0) throw ProtocolError("no render process is left to draw a packet");
  bool allStalled = true;
  for (std::size_t render = 0; render < count; ++render) {
    if (renders_[render].retired) continue;
    allStalled = allStalled && suspectedStalled(render, now);
  }
  // What each render holds of the needs, in one pass over the few renders
  // holding each cell: the rest is missing there.
  std::uint64_t needed = 0;
  std::vector<std::uint64_t> covered(count, 0);
  forEachCellBlock(needs, [&](std::uint32_t cell, std::span<const CellRange> block) {
    std::uint64_t blockSplats = 0;
    for (const CellRange& need : block) blockSplats += need.count;
    needed += blockSplats;
    if (cell >= holders_.size()) return;
    for (const Holding& held : holders_[cell]) {
      std::uint64_t lacking = 0;
      for (const CellRange& need : block)
        lacking += held.spans.uncovered(need.first, static_cast<std::uint32_t>(need.end()));
      covered[held.render] += blockSplats - lacking;
    }
  });
  std::optional<RenderChoice> best;
  std::uint64_t bestWorkload = 0;
  for (std::size_t step = 0; step < count; ++step) {
    const std::size_t render = (rotation_ + step) % count;
    if (renders_[render].retired) continue;
    if (!allStalled && suspectedStalled(render, now)) continue;
    if (candidate && !candidate(render)) continue;
    const std::uint64_t missing = (needed - covered[render]) * sizeof(Splat);
    const double value = costWith(render, missing, splats);
    const std::uint64_t load = workload(render);
    const bool tie = best && value == best->cost;
    if (!best || value < best->cost || (tie && missing < best->missingBytes) ||
        (tie && missing == best->missingBytes && load < bestWorkload)) {
      best = RenderChoice{render, value, missing, {}};
      bestWorkload = load;
    }
  }
  if (best) {
    rotation_ = (best->render + 1) % count;
    best->missing = this->missing(best->render, needs);
  }
  return best;
}

RenderChoice RenderModel::choose(std::span<const CellRange> needs, std::uint64_t splats,
                                 Clock::time_point now) const {
  // Some live render is always a candidate (stalled ones too when all are).
  return *chooseAmong(needs, splats, now, {});
}

std::optional<RenderChoice> RenderModel::chooseApart(std::span<const CellRange> needs,
                                                     std::uint64_t splats, Clock::time_point now,
                                                     std::span<const std::size_t> avoid,
                                                     double slack) const {
  const double least = leastQueuedSeconds(now);
  return chooseAmong(needs, splats, now, [&](std::size_t render) {
    return std::find(avoid.begin(), avoid.end(), render) == avoid.end() &&
           canTakePart(render, least, slack, now);
  });
}

std::optional<RenderChoice> RenderModel::chooseExcept(std::span<const CellRange> needs,
                                                      std::uint64_t splats, Clock::time_point now,
                                                      std::span<const std::uint32_t> avoid) const {
  return chooseAmong(needs, splats, now, [&](std::size_t render) {
    return std::find(avoid.begin(), avoid.end(), render) == avoid.end();
  });
}

RenderChoice RenderModel::chooseNearHome(std::size_t home, std::span<const CellRange> needs,
                                         std::uint64_t splats, Clock::time_point now) const {
  if (liveCount() == 0) throw ProtocolError("no render process is left to draw a packet");
  home %= renders_.size();
  while (renders_[home].retired) home = (home + 1) % renders_.size();
  double leastQueued = std::numeric_limits<double>::infinity();
  for (std::size_t render = 0; render < renders_.size(); ++render) {
    if (renders_[render].retired || render == home || suspectedStalled(render, now)) continue;
    leastQueued = std::min(leastQueued, queuedSeconds(render));
  }
  const bool othersStalled = std::isinf(leastQueued);
  if (othersStalled) return assigned(home, needs, splats);
  const double slack = kHomeSlackPackets * static_cast<double>(splats) * secondsPerSplat();
  if (!suspectedStalled(home, now) && queuedSeconds(home) <= leastQueued + slack) {
    return assigned(home, needs, splats);
  }
  return choose(needs, splats, now);
}

double RenderModel::queuedSeconds(std::size_t render) const {
  return static_cast<double>(workload(render)) * secondsPerSplat(render);
}

RenderChoice RenderModel::assigned(std::size_t render, std::span<const CellRange> needs,
                                   std::uint64_t splats) const {
  RenderChoice choice;
  if (liveCount() == 0) throw ProtocolError("no render process is left to draw a packet");
  choice.render = render % renders_.size();
  while (renders_[choice.render].retired) choice.render = (choice.render + 1) % renders_.size();
  choice.cost = cost(choice.render, needs, splats, &choice.missingBytes);
  choice.missing = missing(choice.render, needs);
  return choice;
}

void RenderModel::retire(std::size_t render) {
  RenderState& state = renders_.at(render);
  for (std::uint32_t cell = 0; cell < holders_.size(); ++cell) dropHolding(cell, render);
  state = RenderState{};
  state.retired = true;
}

std::size_t RenderModel::liveCount() const {
  return static_cast<std::size_t>(std::count_if(renders_.begin(), renders_.end(),
                                                [](const RenderState& s) { return !s.retired; }));
}

void RenderModel::recordPacket(std::size_t render, std::uint64_t packetId, std::uint64_t splats,
                               std::span<const CellRange> ordered, Clock::time_point now) {
  RenderState& state = renders_.at(render);
  if (!state.waitingSince) state.waitingSince = now;
  state.unreported.emplace_back(packetId, splats);
  recordPrefetch(render, ordered);
}

void RenderModel::recordPrefetch(std::size_t render, std::span<const CellRange> ordered) {
  (void)renders_.at(render);
  for (const CellRange& range : ordered) {
    holdingFor(range.cell, render).spans.add(range.first, static_cast<std::uint32_t>(range.end()));
  }
}

std::vector<CellRange> RenderModel::missing(std::size_t render,
                                            std::span<const CellRange> needs) const {
  (void)renders_.at(render);
  std::vector<CellRange> lacking;
  forEachMissing(render, needs, [&](std::uint32_t cell, std::uint32_t begin, std::uint32_t end) {
    lacking.push_back({cell, begin, end - begin});
  });
  return lacking;
}

void RenderModel::applyReport(std::size_t render, const RenderReportView& report,
                              Clock::time_point now) {
  RenderState& state = renders_.at(render);
  if (state.retired) return;  // a report that was on its way when the render was lost
  if (report.packetsDone > state.packetsDone || report.workloadSplats == 0) {
    state.waitingSince.reset();  // progress, or nothing to do
  }
  state.packetsDone = std::max(state.packetsDone, report.packetsDone);
  state.reportedWorkload = report.workloadSplats;
  state.lastPacketSeen = std::max(state.lastPacketSeen, report.lastPacketFromUs);
  std::erase_if(state.unreported,
                [&](const auto& packet) { return packet.first <= state.lastPacketSeen; });
  // An eviction drops what was held and what was on order: data-send
  // forgets the cell too, and the render asks again for what it waits for.
  for (std::uint32_t cell : report.evicted) dropHolding(cell, render);
  for (const CellRange& loaded : report.loaded) {
    Holding& held = holdingFor(loaded.cell, render);
    held.spans.add(loaded.first, static_cast<std::uint32_t>(loaded.end()));
    if (!held.confirmed) {
      held.confirmed = true;
      ++state.confirmedCells;
    }
  }
  if (!state.waitingSince && workload(render) > 0) state.waitingSince = now;
  // Already smoothed by the render process (common to its T_s and T_n).
  if (report.secondsPerSplat > 0.0) state.secondsPerSplat = report.secondsPerSplat;
  if (report.secondsPerByte > 0.0) state.secondsPerByte = report.secondsPerByte;
}

}  // namespace pointillist::traverse
