#include "traverse/core/packet_planner.hpp"

#include <algorithm>
#include <cstdio>
#include <map>

#include "common/run_settings.hpp"
#include "common/splat.hpp"

namespace pointillist::traverse {
TileWalk walkOf(const TraversalResult& result) {
  return TileWalk{result.needs, result.splats, result.ranges, result.needBoxes};
}

std::vector<CellRange> needRanges(const TileWalk& walk, std::size_t firstNeed, std::size_t endNeed,
                                  std::size_t firstRange, std::size_t endRange,
                                  const PacketLayers& layers, std::uint32_t gapSplats) {
  std::vector<CellRange> needs;
  needs.reserve(endRange - firstRange + (endNeed - firstNeed));
  std::size_t range = firstRange;
  for (std::size_t i = firstNeed; i < endNeed; ++i) {
    const CellPrefix& need = walk.needs[i];
    if (layers.neededAsPrefix(need.cell)) {
      if (need.splats > 0) needs.push_back({need.cell, 0, need.splats});
      while (range < endRange && walk.ranges[range].topLevel == need.cell) ++range;
      continue;
    }
    for (; range < endRange && walk.ranges[range].topLevel == need.cell; ++range) {
      const PacketRange& drawn = walk.ranges[range];
      needs.push_back({drawn.topLevel, drawn.offset, drawn.count});
    }
  }
  normalizeCellRanges(needs, gapSplats);
  return needs;
}

TraversalSettings traversalSettings(const v1::RunSettings& settings) {
  TraversalSettings traversal;
  traversal.lodPixels = settings.lod_pixels() > 0.0f ? settings.lod_pixels() : 1.0f;
  traversal.sizeScale = settings.size_scale() > 0.0f ? settings.size_scale() : 1.0f;
  traversal.backfaceCull = settings.backface_cull();
  // Eye-dome lighting draws each tile with a halo: cull for the grown rectangle.
  if (settings.edl()) {
    traversal.marginPixels += static_cast<float>(edlHaloPixels(settings.edl_radius()));
  }
  return traversal;
}

PacketPlanner::PacketPlanner(PeerRanks peers, int selfRank, const v1::RunSettings& settings,
                             std::shared_ptr<const PacketLayers> layers,
                             std::vector<std::uint32_t> owners)
    : peers_(std::move(peers)),
      selfRank_(selfRank),
      selfIndex_(peers_.indexOf(v1::ROLE_TRAVERSE, selfRank)),
      settings_(settings),
      traversal_(traversalSettings(settings)),
      layers_(std::move(layers)),
      owners_(std::move(owners)),
      model_(peers_.renders.size(), costModelOf(settings.cost_model())) {
  model_.setCoreShares({settings.render_core_share().data(),
                        static_cast<std::size_t>(settings.render_core_share_size())});
  if (!layers_ || owners_.size() != layers_->cellCount()) {
    throw UsageError("packet planner: " + std::to_string(owners_.size()) + " owners for " +
                     std::to_string(layers_ ? layers_->cellCount() : 0) + " top-level cells");
  }
}

void PacketPlanner::startWork(Outbox& out) {
  for (std::uint32_t request = 0; request < tileTasksAhead(settings_); ++request) requestWork(out);
}

void PacketPlanner::requestWork(Outbox& out) {
  requestWork(out, v1::TileTask{}, {});
}

void PacketPlanner::requestWork(Outbox& out, const v1::TileTask& task,
                                std::span<const PacketPlan> placed) {
  v1::WorkRequest request;
  request.set_traverse_rank(selfRank_);
  request.set_tasks_done(tasksDone_);
  for (const PacketPlan& plan : placed) {
    v1::TilePlacement* placement = request.add_placements();
    placement->set_frame_id(task.frame_id());
    placement->set_tile_id(task.tile_id());
    placement->set_attempt(task.attempt());
    placement->set_render(static_cast<std::uint32_t>(plan.choice.render));
  }
  out.send(peers_.display, std::move(request));
}

v1::Scheduler PacketPlanner::schedulerFor(const v1::TileTask& task) const {
  return task.has_frame_settings() && task.frame_settings().has_scheduler()
             ? task.frame_settings().scheduler()
             : settings_.scheduler();
}

TraversalSettings PacketPlanner::traversalFor(const v1::TileTask& task) const {
  TraversalSettings traversal = traversal_;
  // The packets' screen boxes (what a render draws lies in them).
  traversal.screenBoxes = true;
  if (task.has_frame_settings() && task.frame_settings().lod_pixels() > 0.0f)
    traversal.lodPixels = task.frame_settings().lod_pixels();
  return traversal;
}

std::optional<Camera> PacketPlanner::lookaheadCamera(const v1::TileTask& task) const {
  const v1::Scheduler scheduler = schedulerFor(task);
  if ((scheduler != v1::SCHEDULER_COST && scheduler != v1::SCHEDULER_REGIONS) ||
      !task.has_lookahead_camera()) {
    return std::nullopt;
  }
  return task.lookahead_camera();
}

std::vector<WalkPart> splitWalk(const TileWalk& walk, std::size_t parts) {
  const std::size_t needs = walk.needs.size();
  // Each need's drawn splats and its block of ranges (ranges are sorted by
  // cell, needs ascending: one block per need).
  std::vector<std::uint64_t> drawn(needs, 0);
  std::vector<std::size_t> rangeStart(needs + 1, walk.ranges.size());
  if (!walk.ranges.empty()) {
    std::size_t range = 0;
    for (std::size_t need = 0; need < needs; ++need) {
      rangeStart[need] = range;
      while (range < walk.ranges.size() && walk.ranges[range].topLevel == walk.needs[need].cell) {
        drawn[need] += walk.ranges[range].count;
        ++range;
      }
    }
    if (range != walk.ranges.size()) {
      throw ProtocolError("tile walk has ranges of top-level cell " +
                          std::to_string(walk.ranges[range].topLevel) + " that it does not need");
    }
  } else if (needs > 0) {
    throw ProtocolError("tile walk has no ranges for its " + std::to_string(needs) + " cells");
  }
  std::vector<std::uint64_t> before(needs + 1, 0);  // splats drawn from needs [0, i)
  for (std::size_t need = 0; need < needs; ++need) before[need + 1] = before[need] + drawn[need];
  const std::uint64_t total = before[needs];

  std::vector<WalkPart> result;
  parts = std::clamp<std::size_t>(parts, 1, std::max<std::size_t>(1, needs));
  std::size_t first = 0;
  for (std::size_t part = 1; part <= parts && first < needs; ++part) {
    std::size_t end = needs;
    if (part < parts) {
      // The cut nearest the share; at least one need in this part, and
      // enough left for the parts after it.
      const double share =
          static_cast<double>(total) * static_cast<double>(part) / static_cast<double>(parts);
      end = static_cast<std::size_t>(
          std::lower_bound(before.begin(), before.end(), static_cast<std::uint64_t>(share)) -
          before.begin());
      if (end > first + 1 &&
          share - static_cast<double>(before[end - 1]) < static_cast<double>(before[end]) - share) {
        --end;
      }
      end = std::clamp(end, first + 1, needs - (parts - part));
    }
    const std::uint64_t splats = before[end] - before[first];
    if (splats > 0 || result.empty()) {
      result.push_back({first, end, rangeStart[first], rangeStart[end], splats});
    } else {
      // An empty run of cells joins the part before it.
      result.back().endNeed = end;
      result.back().endRange = rangeStart[end];
    }
    first = end;
  }
  return result;
}

std::size_t PacketPlanner::partsFor(const v1::TileTask& task, const TileWalk& walk,
                                    TimePoint now) const {
  const std::uint64_t partSplats = task.part_splats();
  if (partSplats == 0 || walk.splats < 2 * partSplats || walk.needs.size() < 2) return 1;
  const v1::Scheduler scheduler = schedulerFor(task);
  if (scheduler != v1::SCHEDULER_COST && scheduler != v1::SCHEDULER_REGIONS) return 1;
  if (!tileSplitAllowed(settings_, task.frame_settings())) return 1;
  // Instanced sections are not the point kernel's to draw.
  for (const PacketRange& range : walk.ranges) {
    if (range.section) return 1;
  }
  // Parts go to renders that can take them about as soon as the least loaded
  // could take the whole tile; one that stopped drawing soon falls out.
  const double tileSeconds = static_cast<double>(walk.splats) * model_.secondsPerSplat();
  return std::min<std::size_t>(
      {walk.splats / partSplats, model_.rendersForParts(tileSeconds, now), walk.needs.size()});
}

std::vector<PacketPlan> PacketPlanner::planPackets(const v1::TileTask& task, const TileWalk& walk,
                                                   std::span<const CellPrefix> ahead, TimePoint now,
                                                   Outbox& out) {
  for (const CellPrefix& need : walk.needs) {
    if (need.cell >= layers_->cellCount() || need.splats > layers_->totalSplats(need.cell)) {
      throw ProtocolError("tile walk needs " + std::to_string(need.splats) +
                          " splats of top-level cell " + std::to_string(need.cell) +
                          ", beyond the dataset's packets");
    }
  }
  if (walk.needs.empty() && walk.ranges.empty() && walk.splats == 0) {
    // Nothing in this rect: a render would only clear it and send its pixels
    // back. At a large R such tiles are a large share of the packets, and
    // they pile onto renders whose queues hold few splats.
    v1::TileImageHeader background;
    background.set_frame_id(task.frame_id());
    background.set_tile_id(task.tile_id());
    *background.mutable_rect() = task.rect();
    background.set_format(v1::PIXEL_FORMAT_BACKGROUND);
    background.set_render_rank(-1);
    background.set_attempt(task.attempt());
    background.set_traverse_rank(selfRank_);
    out.send(peers_.display, std::move(background));
    ++emptyTiles_;
    ++tasksDone_;
    requestWork(out);
    return {};
  }
  std::vector<WalkPart> parts;
  if (const std::size_t count = partsFor(task, walk, now); count > 1) {
    parts = splitWalk(walk, count);
  }
  if (parts.size() < 2) {
    parts.assign(1, WalkPart{0, walk.needs.size(), 0, walk.ranges.size(), walk.splats});
  }
  std::vector<PacketPlan> plans;
  plans.reserve(parts.size());
  const auto count = static_cast<std::uint32_t>(parts.size());
  // Renders already drawing a part of this tile (planPart prefers others).
  std::vector<std::size_t> taken;
  for (std::uint32_t index = 0; index < count; ++index) {
    plans.push_back(planPart(task, walk, parts[index], index, count,
                             index == 0 ? ahead : std::span<const CellPrefix>(), taken, now, out));
    taken.push_back(plans.back().choice.render);
  }
  if (count > 1) {
    ++tilesSplit_;
    partsSent_ += count;
  }
  ++tasksDone_;
  splatsPacked_ += walk.splats;
  requestWork(out, task, plans);
  return plans;
}

PacketPlan PacketPlanner::planPart(const v1::TileTask& task, const TileWalk& walk,
                                   const WalkPart& part, std::uint32_t partIndex,
                                   std::uint32_t partCount, std::span<const CellPrefix> ahead,
                                   std::span<const std::size_t> taken, TimePoint now, Outbox& out) {
  PacketPlan plan;
  plan.splats = part.splats;
  plan.partIndex = partIndex;
  plan.partCount = partCount;
  plan.needs = needRanges(walk, part.firstNeed, part.endNeed, part.firstRange, part.endRange,
                          *layers_, needGapSplats(settings_));
  const v1::Scheduler scheduler = schedulerFor(task);
  if (scheduler == v1::SCHEDULER_COST || (scheduler == v1::SCHEDULER_REGIONS && partIndex > 0)) {
    // The parts after the first go where the cost function sends them: the
    // region's render already has the first.
    plan.choice = model_.choose(plan.needs, part.splats, now);
    if (std::find(taken.begin(), taken.end(), plan.choice.render) != taken.end()) {
      // Stacked on a render that draws another part, this part waits about
      // its own drawing time; elsewhere it runs beside it. So another render
      // (one that could start before the least loaded could draw the tile
      // whole) wins if it costs at most that much more, data included.
      const double partSeconds = static_cast<double>(part.splats) * model_.secondsPerSplat();
      auto spread = model_.chooseApart(plan.needs, part.splats, now, taken,
                                       static_cast<double>(walk.splats) * model_.secondsPerSplat());
      if (spread && spread->cost <= plan.choice.cost + partSeconds)
        plan.choice = std::move(*spread);
    }
  } else if (scheduler == v1::SCHEDULER_REGIONS) {
    plan.choice = model_.chooseNearHome(task.assigned_render(), plan.needs, part.splats, now);
  } else {
    plan.choice = model_.assigned(task.assigned_render(), plan.needs, part.splats);
  }
  const auto& avoid = task.avoid_renders();
  if (std::find(avoid.begin(), avoid.end(), plan.choice.render) != avoid.end()) {
    // The display holds a tile of that render overdue: wherever else it can.
    if (auto elsewhere = model_.chooseExcept(
            plan.needs, part.splats, now,
            std::span<const std::uint32_t>(avoid.data(), static_cast<std::size_t>(avoid.size())))) {
      plan.choice = std::move(*elsewhere);
      ++renderAvoided_;
    }
  }
  const RenderChoice& choice = plan.choice;
  plan.renderRank = peers_.renders.at(choice.render);

  plan.orderedBytesHeldElsewhere =
      model_.splatsHeldElsewhere(choice.render, choice.missing) * sizeof(Splat);
  bytesOrderedHeldElsewhere_ += plan.orderedBytesHeldElsewhere;
  // What it lacks counts as on its way from now on (the prefetch below
  // orders only what is not).
  model_.recordPacket(choice.render, packetsSent_ + 1, part.splats, choice.missing, now);

  // Order what the chosen render lacks from the data-send processes owning it.
  std::map<std::uint32_t, std::vector<CellRange>> orders;
  for (const CellRange& range : choice.missing) orders[owners_.at(range.cell)].push_back(range);
  // Prefetch along the camera path: what this rect will need a few frames on
  // goes to the render drawing it now, which the cost function then favours
  // for that part of the screen. The lookahead walk gives each cell the
  // prefix its distance probably needs.
  if (!ahead.empty()) {
    std::vector<CellRange> wanted;
    wanted.reserve(ahead.size());
    for (const CellPrefix& prefix : ahead) {
      if (prefix.cell >= layers_->cellCount()) {
        throw ProtocolError("lookahead walk found top-level cell " + std::to_string(prefix.cell) +
                            " beyond the dataset's " + std::to_string(layers_->cellCount()));
      }
      if (prefix.splats > 0) wanted.push_back({prefix.cell, 0, prefix.splats});
    }
    normalizeCellRanges(wanted);
    for (const CellRange& range : model_.missing(choice.render, wanted)) {
      const std::uint64_t bytes = std::uint64_t{range.count} * sizeof(Splat);
      if (plan.prefetchBytes + bytes > kPrefetchBudgetBytes) break;
      plan.prefetchBytes += bytes;
      plan.prefetch.push_back(range);
      orders[owners_.at(range.cell)].push_back(range);
    }
    model_.recordPrefetch(choice.render, plan.prefetch);
    cellsPrefetched_ += plan.prefetch.size();
    bytesPrefetched_ += plan.prefetchBytes;
  }
  for (auto& [owner, ranges] : orders) {
    normalizeCellRanges(ranges);
    v1::SendOrder order;
    order.set_render_rank(plan.renderRank);
    order.set_requester_rank(selfRank_);
    order.set_order_id(++ordersSent_);
    order.set_frame_id(task.frame_id());
    addRangeFields(ranges, *order.mutable_range_top_level(), *order.mutable_range_first(),
                   *order.mutable_range_count());
    out.send(peers_.datasends.at(owner), std::move(order));
  }

  v1::RenderPacket packet;
  packet.set_frame_id(task.frame_id());
  packet.set_tile_id(task.tile_id());
  *packet.mutable_camera() = task.camera();
  *packet.mutable_rect() = task.rect();
  packet.set_timestamp_ns(task.timestamp_ns());
  packet.set_attempt(task.attempt());
  addRangeFields(plan.needs, *packet.mutable_need_top_level(), *packet.mutable_need_first(),
                 *packet.mutable_need_count());
  const std::span<const PacketRange> ranges =
      walk.ranges.subspan(part.firstRange, part.endRange - part.firstRange);
  const int rangeCount = static_cast<int>(ranges.size());
  packet.mutable_range_top_level()->Reserve(rangeCount);
  packet.mutable_range_offset()->Reserve(rangeCount);
  packet.mutable_range_count()->Reserve(rangeCount);
  for (const PacketRange& range : ranges) {
    packet.add_range_top_level(range.topLevel);
    packet.add_range_offset(range.offset);
    packet.add_range_count(range.count);
  }
  packet.set_total_splats(part.splats);
  packet.set_traverse_rank(selfRank_);
  packet.set_packet_id(++packetsSent_);
  packet.set_ordered_bytes(choice.missingBytes);
  packet.set_ordered_bytes_held_elsewhere(plan.orderedBytesHeldElsewhere);
  packet.set_chosen_cost(choice.cost);
  packet.set_prefetch_bytes(plan.prefetchBytes);
  if (partCount > 1) {
    packet.set_part_index(partIndex);
    packet.set_part_count(partCount);
  }
  if (!walk.needBoxes.empty() && walk.needBoxes.size() == walk.needs.size()) {
    ScreenBox box;
    for (std::size_t i = part.firstNeed; i < part.endNeed; ++i) box.add(walk.needBoxes[i]);
    *packet.mutable_screen_box() = clipScreenBox(box, task.rect());
  }
  if (task.has_frame_settings()) *packet.mutable_frame_settings() = task.frame_settings();
  out.send(plan.renderRank, std::move(packet));

  maxPacketBytes_ = std::max(maxPacketBytes_, rangeSplats(plan.needs) * sizeof(Splat));
  cellsOrdered_ += choice.missing.size();
  bytesOrdered_ += choice.missingBytes;
  return plan;
}

void PacketPlanner::applyReport(int sourceRank, const v1::RenderReport& report, TimePoint now) {
  const std::size_t render = peers_.indexOf(v1::ROLE_RENDER, sourceRank);
  RenderReportView view;
  view.workloadSplats = report.workload_splats();
  const std::vector<CellRange> loaded =
      rangesFromFields(report.loaded_top_level(), report.loaded_first(), report.loaded_count(),
                       "render report from rank " + std::to_string(sourceRank));
  view.loaded = loaded;
  view.evicted = {report.evicted_cells().data(),
                  static_cast<std::size_t>(report.evicted_cells_size())};
  view.secondsPerSplat = report.seconds_per_splat();
  view.secondsPerByte = report.seconds_per_byte();
  if (selfIndex_ < static_cast<std::size_t>(report.last_packet_from_traverse_size())) {
    view.lastPacketFromUs = report.last_packet_from_traverse(static_cast<int>(selfIndex_));
  }
  view.packetsDone = report.packets_done();
  model_.applyReport(render, view, now);
}

void PacketPlanner::renderLost(int renderRank) {
  model_.retire(peers_.indexOf(v1::ROLE_RENDER, renderRank));
}

std::string PacketPlanner::summary() const {
  char line[480];
  std::snprintf(
      line, sizeof line,
      "tasks=%llu splats=%llu ordered_cells=%llu ordered_bytes=%llu "
      "ordered_bytes_held_elsewhere=%llu prefetched_cells=%llu prefetched_bytes=%llu "
      "largest_tile_data=%.2fMiB "
      "tiles_split=%llu parts=%llu empty_tiles=%llu avoided_suspects=%llu T_s=%.3gs/splat "
      "T_n=%.3gs/B",
      static_cast<unsigned long long>(tasksDone_), static_cast<unsigned long long>(splatsPacked_),
      static_cast<unsigned long long>(cellsOrdered_),
      static_cast<unsigned long long>(bytesOrdered_),
      static_cast<unsigned long long>(bytesOrderedHeldElsewhere_),
      static_cast<unsigned long long>(cellsPrefetched_),
      static_cast<unsigned long long>(bytesPrefetched_),
      static_cast<double>(maxPacketBytes_) / 1048576.0,
      static_cast<unsigned long long>(tilesSplit_), static_cast<unsigned long long>(partsSent_),
      static_cast<unsigned long long>(emptyTiles_), static_cast<unsigned long long>(renderAvoided_),
      model_.secondsPerSplat(), model_.secondsPerByte());
  return line;
}

}  // namespace pointillist::traverse
