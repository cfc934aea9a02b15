#include "common/run_settings.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>

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

v1::Renderer parseRenderer(const std::string& name) {
  if (name == "auto") return v1::RENDERER_AUTO;
  if (name == "gl") return v1::RENDERER_GL;
  if (name == "cpu") return v1::RENDERER_CPU;
  throw UsageError("renderer '" + name + "' is not one of: auto, gl, cpu");
}

const char* rendererName(v1::Renderer renderer) {
  switch (renderer) {
    case v1::RENDERER_GL:
      return "gl";
    case v1::RENDERER_CPU:
      return "cpu";
    default:
      return "auto";
  }
}

v1::Scheduler parseScheduler(const std::string& name) {
  if (name == "cost") return v1::SCHEDULER_COST;
  if (name == "round-robin") return v1::SCHEDULER_ROUND_ROBIN;
  if (name == "static") return v1::SCHEDULER_STATIC;
  if (name == "equalizer") return v1::SCHEDULER_EQUALIZER;
  if (name == "regions") return v1::SCHEDULER_REGIONS;
  throw UsageError("scheduler '" + name +
                   "' is not one of: cost, regions, round-robin, static, equalizer");
}

void parseTileSplit(const std::string& text, v1::RunSettings& settings) {
  if (text == "auto" || text == "off" || text == "share") {
    settings.set_no_tile_split(text == "off");
    settings.set_tile_part_splats(0);
    settings.set_tile_part_untuned(text == "share");
    return;
  }
  std::uint64_t splats = 0;
  const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), splats);
  if (error != std::errc() || end != text.data() + text.size() || splats == 0) {
    throw UsageError("--tile-split takes auto, share, off or a part size in splats (>= 1), not '" +
                     text + "'");
  }
  settings.set_no_tile_split(false);
  settings.set_tile_part_splats(splats);
  settings.set_tile_part_untuned(false);
}

std::string tileSplitName(const v1::RunSettings& settings) {
  if (settings.no_tile_split()) return "off";
  if (settings.tile_part_splats() > 0) return std::to_string(settings.tile_part_splats());
  return settings.tile_part_untuned() ? "share" : "auto";
}

bool tileSplitAllowed(const v1::RunSettings& run, const v1::FrameSettings& frame) {
  if (run.no_tile_split() || run.edl() || frame.tile_depth()) return false;
  const v1::RenderMode mode =
      frame.mode() != v1::RENDER_MODE_UNSPECIFIED ? frame.mode() : run.mode();
  const bool points = mode == v1::RENDER_MODE_POINTS || mode == v1::RENDER_MODE_UNSPECIFIED;
  return points && resolveRenderer(run.renderer(), mode) == v1::RENDERER_CPU;
}

std::uint32_t needGapSplats(const v1::RunSettings& settings) {
  return settings.has_need_gap_splats() ? settings.need_gap_splats() : kNeedGapSplatsCopied;
}

std::optional<std::uint32_t> parseNeedGapSplats(const std::string& text) {
  if (text == "auto") return std::nullopt;
  std::uint32_t gap = 0;
  const char* end = text.data() + text.size();
  const auto [at, error] = std::from_chars(text.data(), end, gap);
  if (error != std::errc() || at != end || gap > 65536) {
    throw UsageError("--need-gap '" + text + "' is not auto or a count of splats from 0 to 65536");
  }
  return gap;
}

std::uint32_t tileTasksAhead(const v1::RunSettings& settings) {
  return settings.tile_tasks_ahead() > 0 ? settings.tile_tasks_ahead() : kDefaultTileTasksAhead;
}

std::uint32_t autoTileTasksAhead(double tilesPerFrame, std::uint32_t traverses) {
  const double perTraverse =
      tilesPerFrame / static_cast<double>(std::max<std::uint32_t>(1, traverses));
  const double count = std::ceil(perTraverse / static_cast<double>(kTilesPerAutoTileTask));
  return static_cast<std::uint32_t>(std::clamp(count, static_cast<double>(kDefaultTileTasksAhead),
                                               static_cast<double>(kMaxAutoTileTasksAhead)));
}

std::uint32_t parseTileTasksAhead(const std::string& text) {
  if (text == "auto") return 0;
  std::uint32_t count = 0;
  const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), count);
  if (error != std::errc() || end != text.data() + text.size() || count == 0 || count > 64) {
    throw UsageError("--tile-tasks-ahead takes auto or a count from 1 to 64, not '" + text + "'");
  }
  return count;
}

float parseRenderCoreShare(const std::string& text) {
  if (text == "auto") return 0.0f;
  float share = 0.0f;
  const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), share);
  if (error != std::errc() || end != text.data() + text.size() || !(share > 0.0f) || share > 1.0f) {
    throw UsageError("--render-core-share takes auto or a share above 0 and at most 1, not '" +
                     text + "'");
  }
  return share;
}

std::string autoTileTasksAheadRule() {
  return "one per " + std::to_string(kTilesPerAutoTileTask) +
         " tiles a traverse walks per frame, from " + std::to_string(kDefaultTileTasksAhead) +
         " to " + std::to_string(kMaxAutoTileTasksAhead);
}

const char* schedulerName(v1::Scheduler scheduler) {
  switch (scheduler) {
    case v1::SCHEDULER_COST:
      return "cost";
    case v1::SCHEDULER_ROUND_ROBIN:
      return "round-robin";
    case v1::SCHEDULER_STATIC:
      return "static";
    case v1::SCHEDULER_EQUALIZER:
      return "equalizer";
    case v1::SCHEDULER_REGIONS:
      return "regions";
    default:
      return "unknown";
  }
}

v1::Renderer resolveRenderer(v1::Renderer renderer, v1::RenderMode mode) {
  const bool points = mode == v1::RENDER_MODE_POINTS || mode == v1::RENDER_MODE_UNSPECIFIED;
  if (renderer == v1::RENDERER_CPU && !points) {
    throw UsageError("the cpu renderer draws points only; mode " + v1::RenderMode_Name(mode) +
                     " needs --renderer gl (or auto)");
  }
  if (renderer == v1::RENDERER_GL || renderer == v1::RENDERER_CPU) return renderer;
  return points ? v1::RENDERER_CPU : v1::RENDERER_GL;
}

std::uint32_t edlHaloPixels(float radius) {
  return static_cast<std::uint32_t>(std::ceil(std::clamp(radius, 0.0f, kMaxEdlRadius)));
}

void checkEdl(v1::RenderMode mode, float strength, float radius) {
  const auto text = [](float value) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%g", static_cast<double>(value));
    return std::string(buffer);
  };
  if (!(strength > 0.0f && strength <= 100.0f)) {
    throw UsageError("--edl-strength " + text(strength) + " is not in (0, 100]");
  }
  if (!(radius >= 1.0f && radius <= kMaxEdlRadius)) {
    throw UsageError("--edl-radius " + text(radius) + " is not in [1, " + text(kMaxEdlRadius) +
                     "] pixels");
  }
  if (mode == v1::RENDER_MODE_BLENDED) {
    throw UsageError(
        "--edl shades points and splats, not the blended mode (its depth buffer holds the "
        "blend pass's pushed-back depths); use --mode points or splats, or drop --edl");
  }
}

void checkInstancedSections(const v1::RunSettings& run, const std::string& dataset) {
  if (!run.instanced_sections())
    throw UsageError("--mode instanced: " + dataset +
                     " has no instanced sections; build it with pointillist-preprocess "
                     "--instanced");
}

void checkStatisticalHierarchy(const v1::RunSettings& run, const std::string& dataset) {
  if (!run.statistical_hierarchy())
    throw UsageError("--mode statistical: " + dataset +
                     " has no statistical hierarchy; build it with pointillist-preprocess "
                     "--statistical");
}

v1::RunSettings frameRunSettings(const v1::RunSettings& run, const v1::FrameSettings& frame) {
  v1::RunSettings settings = run;
  if (frame.mode() != v1::RENDER_MODE_UNSPECIFIED) settings.set_mode(frame.mode());
  if (frame.lod_pixels() > 0.0f) settings.set_lod_pixels(frame.lod_pixels());
  if (frame.has_scheduler()) settings.set_scheduler(frame.scheduler());
  return settings;
}

void checkFrameSettings(const v1::RunSettings& run, const v1::FrameSettings& frame) {
  const v1::RenderMode mode = frame.mode();
  if (mode != v1::RENDER_MODE_UNSPECIFIED && mode != v1::RENDER_MODE_POINTS &&
      mode != v1::RENDER_MODE_SPLATS && mode != v1::RENDER_MODE_BLENDED &&
      mode != v1::RENDER_MODE_INSTANCED && mode != v1::RENDER_MODE_STATISTICAL) {
    throw UsageError("mode " + v1::RenderMode_Name(mode) + " is not available");
  }
  if (mode == v1::RENDER_MODE_INSTANCED) checkInstancedSections(run, "this job's dataset");
  if (mode == v1::RENDER_MODE_STATISTICAL) checkStatisticalHierarchy(run, "this job's dataset");
  if (mode != v1::RENDER_MODE_UNSPECIFIED) {
    resolveRenderer(run.renderer(), mode);
    if (run.edl()) checkEdl(mode, run.edl_strength(), run.edl_radius());
  }
  if (!std::isfinite(frame.lod_pixels()) || frame.lod_pixels() < 0.0f) {
    throw UsageError("a level of detail must be a positive number of pixels");
  }
  if (frame.has_scheduler() && !v1::Scheduler_IsValid(frame.scheduler())) {
    throw UsageError("unknown scheduler " + std::to_string(frame.scheduler()));
  }
}

}  // namespace pointillist
