#pragma once
// A traverse process's model of every render process (seed 003 §4.3, §4.5):
// pending work and the ranges it holds of every top-level cell
// (common/cell_ranges.hpp), kept from the renders' reports, and the cost
// function that picks where a render packet goes. Missing bytes are the
// splats of the ranges a packet needs that a render neither holds nor has on
// order. As the paper writes it:
//   Cost(i) = workload(i) * T_s + missing_bytes(i) * T_n
// As an option the transfer is taken to overlap the work already queued there
// (data-send streams the cells while the render draws), see docs/scheduling.md:
//   Cost(i) = max(workload(i) * T_s, missing_bytes(i) * T_n) + packet_splats * T_s
// Where processes outnumber a machine's cores, workload(i) * T_s is weighed by
// the share of a core each has (common/core_share.hpp, docs/scheduling.md §11).
// T_s (seconds per splat) and T_n (seconds per byte) are measured by each
// render process while running and kept per process, so a render process on a
// slower node (or behind a slower link) gets proportionally less work while it
// has work; one that is idle or not measured yet counts as the mean of those
// that are (a stale figure must not keep work from it for good).
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <vector>

#include "common/cell_ranges.hpp"
#include "common/run_settings.hpp"
#include "pointillist.pb.h"

namespace pointillist::traverse {

struct RenderReportView {
  std::uint64_t workloadSplats = 0;
  // Applied in this order: cells dropped whole, then ranges stored since.
  std::span<const std::uint32_t> evicted{};
  std::span<const CellRange> loaded{};
  double secondsPerSplat = 0.0;  // 0: not measured yet
  double secondsPerByte = 0.0;   // 0: not measured yet
  // Highest packet id from this traverse the render had received when reporting.
  std::uint64_t lastPacketFromUs = 0;
  std::uint64_t packetsDone = 0;  // packets the render has finished in all
};

// At most this much data ordered ahead along the camera path per tile, so a
// sharp turn of the camera cannot flood the links ahead of waiting packets.
inline constexpr std::uint64_t kPrefetchBudgetBytes = 8ull << 20;

enum class CostModel {
  Paper,    // seed 003 as written: the transfer adds to the queue (default)
  Overlap,  // transfers overlap the queued work
};

v1::CostModel costModelMessage(CostModel model);
CostModel costModelOf(v1::CostModel model);

struct RenderChoice {
  std::size_t render = 0;  // index among render processes
  double cost = 0.0;
  std::uint64_t missingBytes = 0;
  std::vector<CellRange> missing;  // ranges to order for it (what it lacks of the needs)
};

class RenderModel {
 public:
  using Clock = std::chrono::steady_clock;

  RenderModel(std::size_t renderCount, CostModel costModel = costModelOf(kDefaultCostModel));
  void setCostModel(CostModel model) { costModel_ = model; }
  // Per render process: the share of a core each job process has on its
  // machine (common/core_share.hpp); the cost function weighs the render's
  // queue by it. Empty or missing entries: 1 (seed 003: a node each).
  void setCoreShares(std::span<const float> shares);
  CostModel costModel() const { return costModel_; }

  // Cost of sending a packet of `splats` splats that needs `needs` to render i.
  double cost(std::size_t render, std::span<const CellRange> needs, std::uint64_t splats,
              std::uint64_t* missingBytes = nullptr) const;
  // The render with the lowest cost; ties go to the fewest missing bytes, then
  // the lowest pending work, then rotate from the last choice so idle renders
  // share the first frames.
  // A render that has had work for much longer than that work should take
  // without finishing a packet is suspected stalled and only chosen when every
  // render is.
  RenderChoice choose(std::span<const CellRange> needs, std::uint64_t splats,
                      Clock::time_point now) const;
  // The same choice among the renders not in `avoid` (those drawing the other
  // parts of a split tile) that may take a part (rendersForParts with
  // `slack`); nullopt when there is none.
  std::optional<RenderChoice> chooseApart(std::span<const CellRange> needs, std::uint64_t splats,
                                          Clock::time_point now, std::span<const std::size_t> avoid,
                                          double slack) const;
  // The cost function's choice among the renders not in `avoid` (the display
  // suspects them: they hold a tile past its deadline); nullopt when none is
  // left.
  std::optional<RenderChoice> chooseExcept(std::span<const CellRange> needs, std::uint64_t splats,
                                           Clock::time_point now,
                                           std::span<const std::uint32_t> avoid) const;
  bool suspectedStalled(std::size_t render, Clock::time_point now) const;
  // Renders a split tile's parts may go to: live, not suspected stalled,
  // whose queue holds at most `slack` seconds more than the least loaded
  // one's and that finished a packet within twice their queue's time and the
  // slack (one that stopped drawing falls out at once, not after a second).
  std::size_t rendersForParts(double slack, Clock::time_point now) const;
  // The regions scheduler: the tile's own region's render `home`, unless its
  // queue holds more than kHomeSlackPackets of this packet's time beyond the
  // least loaded live render's, or it is suspected stalled; then the cost
  // function chooses among all. So no render idles while another holds more
  // than two tiles' worth of work.
  RenderChoice chooseNearHome(std::size_t home, std::span<const CellRange> needs,
                              std::uint64_t splats, Clock::time_point now) const;
  static constexpr double kHomeSlackPackets = 2.0;
  // The same figures for a render chosen by someone else (other schedulers).
  RenderChoice assigned(std::size_t render, std::span<const CellRange> needs,
                        std::uint64_t splats) const;

  // Records that a packet went to `render` with the given id, and that its
  // missing ranges were ordered (they count as present from now on).
  void recordPacket(std::size_t render, std::uint64_t packetId, std::uint64_t splats,
                    std::span<const CellRange> ordered, Clock::time_point now);
  // Ranges ordered for `render` ahead of any packet (prefetch along the camera path).
  void recordPrefetch(std::size_t render, std::span<const CellRange> ordered);
  // Of `needs` (sorted by cell), what `render` neither holds nor has on order.
  std::vector<CellRange> missing(std::size_t render, std::span<const CellRange> needs) const;
  // The splats of those.
  std::uint64_t missingSplats(std::size_t render, std::span<const CellRange> needs) const;
  // Of `ranges`, the splats some render other than `render` holds or has on
  // order: bytes that move because work moved, not because the view did.
  std::uint64_t splatsHeldElsewhere(std::size_t render, std::span<const CellRange> ranges) const;
  void applyReport(std::size_t render, const RenderReportView& report, Clock::time_point now);

  std::uint64_t workload(std::size_t render) const;  // reported + sent since the report
  double queuedSeconds(std::size_t render) const;    // workload * its T_s
  // The splats of `cell` that `render` holds or has on order.
  std::uint64_t heldSplats(std::size_t render, std::uint32_t cell) const;
  std::size_t cachedCellCount(std::size_t render) const;
  // T_s and T_n of one render process as the cost function uses them.
  double secondsPerSplat(std::size_t render) const;
  double secondsPerByte(std::size_t render) const;
  // Means over the render processes that have reported them (or the defaults).
  double secondsPerSplat() const;
  double secondsPerByte() const;
  std::size_t renderCount() const { return renders_.size(); }
  // The render is gone (the display said so): never chosen again, its figures
  // leave the means. A packet assigned to it goes to the next live render.
  void retire(std::size_t render);
  bool retired(std::size_t render) const { return renders_.at(render).retired; }
  std::size_t liveCount() const;

 private:
  // Calls gap(cell, begin, end) for each stretch of `needs` that `render`
  // neither holds nor has on order.
  template <class Gap>
  void forEachMissing(std::size_t render, std::span<const CellRange> needs, Gap&& gap) const;
  // The cost function's figure for `render` when `missingBytes` must move there.
  double costWith(std::size_t render, std::uint64_t missingBytes, std::uint64_t splats) const;
  // The lowest-cost render for which `candidate` holds (every live one when
  // empty); nullopt when none does.
  std::optional<RenderChoice> chooseAmong(std::span<const CellRange> needs, std::uint64_t splats,
                                          Clock::time_point now,
                                          const std::function<bool(std::size_t)>& candidate) const;
  double leastQueuedSeconds(Clock::time_point now) const;
  bool canTakePart(std::size_t render, double least, double slack, Clock::time_point now) const;

  struct RenderState {
    std::uint64_t reportedWorkload = 0;
    std::uint64_t lastPacketSeen = 0;
    // Packets sent to this render after its last report: id -> splats.
    std::vector<std::pair<std::uint64_t, std::uint64_t>> unreported;
    std::size_t confirmedCells = 0;  // cells a report said it holds some of
    std::uint64_t packetsDone = 0;
    // Since when the render has had work and finished nothing.
    std::optional<Clock::time_point> waitingSince;
    double secondsPerSplat = 0.0;  // as last reported; 0: not measured yet
    double secondsPerByte = 0.0;
    double coreShare = 1.0;
    bool retired = false;
  };
  static constexpr double kDefaultSecondsPerSplat = 2e-7;  // until measured: 5 M splats/s
  static constexpr double kDefaultSecondsPerByte = 1e-8;   // until measured: 100 MB/s
  std::vector<RenderState> renders_;
  // What a render holds of a cell or has on order: kept per cell, so that
  // the cost of every render is found in one pass over a packet's needs and
  // the few renders holding each (not a lookup per render and cell).
  struct Holding {
    std::uint32_t render = 0;
    bool confirmed = false;  // a report said it holds some of the cell
    SpanSet spans;           // held, or on order
  };
  std::vector<std::vector<Holding>> holders_;  // by cell
  const Holding* holding(std::uint32_t cell, std::size_t render) const;
  Holding& holdingFor(std::uint32_t cell, std::size_t render);
  void dropHolding(std::uint32_t cell, std::size_t render);
  CostModel costModel_;
  mutable std::size_t rotation_ = 0;
};

}  // namespace pointillist::traverse
