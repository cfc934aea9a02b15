// The settings a run hands every process, and what a served frame may change
// of them (set_options): the checks the service answers with.
#include "common/run_settings.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "common/errors.hpp"

namespace pointillist {
namespace {

v1::RunSettings run(v1::Renderer renderer = v1::RENDERER_AUTO, bool edl = false) {
  v1::RunSettings settings;
  settings.set_mode(v1::RENDER_MODE_POINTS);
  settings.set_lod_pixels(1.0f);
  settings.set_size_scale(1.5f);
  settings.set_scheduler(v1::SCHEDULER_COST);
  settings.set_renderer(renderer);
  settings.set_edl(edl);
  settings.set_edl_strength(kDefaultEdlStrength);
  settings.set_edl_radius(kDefaultEdlRadius);
  return settings;
}

v1::FrameSettings frame(v1::RenderMode mode, float lod = 0.0f) {
  v1::FrameSettings settings;
  settings.set_mode(mode);
  settings.set_lod_pixels(lod);
  return settings;
}

TEST(RunSettings, AFramesSettingsReplaceOnlyWhatTheySet) {
  const v1::RunSettings base = run();
  const v1::RunSettings same = frameRunSettings(base, {});
  EXPECT_EQ(same.SerializeAsString(), base.SerializeAsString());

  v1::FrameSettings served = frame(v1::RENDER_MODE_SPLATS, 2.5f);
  served.set_scheduler(v1::SCHEDULER_STATIC);
  const v1::RunSettings drawn = frameRunSettings(base, served);
  EXPECT_EQ(drawn.mode(), v1::RENDER_MODE_SPLATS);
  EXPECT_EQ(drawn.lod_pixels(), 2.5f);
  EXPECT_EQ(drawn.scheduler(), v1::SCHEDULER_STATIC);
  EXPECT_EQ(drawn.size_scale(), 1.5f) << "size scale stays the run's";
}

TEST(RunSettings, AFrameMayAskOnlyForWhatTheRunCanDraw) {
  EXPECT_NO_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_SPLATS, 2.0f)));
  EXPECT_NO_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_BLENDED)));
  // The cpu kernel draws points only.
  EXPECT_NO_THROW(checkFrameSettings(run(v1::RENDERER_CPU), frame(v1::RENDER_MODE_POINTS)));
  EXPECT_THROW(checkFrameSettings(run(v1::RENDERER_CPU), frame(v1::RENDER_MODE_SPLATS)),
               UsageError);
  // Eye-dome lighting cannot shade the blended mode.
  EXPECT_THROW(checkFrameSettings(run(v1::RENDERER_AUTO, true), frame(v1::RENDER_MODE_BLENDED)),
               UsageError);
  EXPECT_NO_THROW(checkFrameSettings(run(v1::RENDERER_AUTO, true), frame(v1::RENDER_MODE_SPLATS)));
  // The instanced mode needs a dataset with instanced sections and the GL renderer.
  EXPECT_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_INSTANCED)), UsageError);
  v1::RunSettings withSections = run();
  withSections.set_instanced_sections(true);
  EXPECT_NO_THROW(checkFrameSettings(withSections, frame(v1::RENDER_MODE_INSTANCED)));
  withSections.set_renderer(v1::RENDERER_CPU);
  EXPECT_THROW(checkFrameSettings(withSections, frame(v1::RENDER_MODE_INSTANCED)), UsageError);
  // The statistical mode likewise needs hierarchies and the GL renderer.
  EXPECT_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_STATISTICAL)), UsageError);
  v1::RunSettings withHierarchy = run();
  withHierarchy.set_statistical_hierarchy(true);
  EXPECT_NO_THROW(checkFrameSettings(withHierarchy, frame(v1::RENDER_MODE_STATISTICAL)));
  withHierarchy.set_renderer(v1::RENDERER_CPU);
  EXPECT_THROW(checkFrameSettings(withHierarchy, frame(v1::RENDER_MODE_STATISTICAL)), UsageError);
  // Levels of detail that are no size.
  EXPECT_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_POINTS, -1.0f)), UsageError);
  EXPECT_THROW(checkFrameSettings(run(), frame(v1::RENDER_MODE_POINTS, NAN)), UsageError);
  v1::FrameSettings unknown;
  unknown.set_scheduler(static_cast<v1::Scheduler>(99));
  EXPECT_THROW(checkFrameSettings(run(), unknown), UsageError);
}

TEST(RunSettings, SchedulerNamesRoundTrip) {
  for (const auto scheduler : {v1::SCHEDULER_COST, v1::SCHEDULER_ROUND_ROBIN, v1::SCHEDULER_STATIC,
                               v1::SCHEDULER_EQUALIZER}) {
    EXPECT_EQ(parseScheduler(schedulerName(scheduler)), scheduler);
  }
  EXPECT_THROW(parseScheduler("fastest"), UsageError);
}

// auto: one request per 16 tiles a traverse walks per frame, at least the
// old default (a small job decides as before), at most 8.
TEST(RunSettings, TileTasksAheadAutoGrowsWithTheTilesEachTraverseWalks) {
  EXPECT_EQ(autoTileTasksAhead(8, 2), kDefaultTileTasksAhead);  // the 1,2,1,4 default job
  EXPECT_EQ(autoTileTasksAhead(64, 2), 2u);
  EXPECT_EQ(autoTileTasksAhead(65, 2), 3u);
  EXPECT_EQ(autoTileTasksAhead(256, 4), 4u);
  EXPECT_EQ(autoTileTasksAhead(256, 2), 8u);
  EXPECT_EQ(autoTileTasksAhead(8192, 4), kMaxAutoTileTasksAhead);
  EXPECT_EQ(autoTileTasksAhead(50, 0), 4u) << "no traverse counts as one";
  for (double tiles = 1; tiles < 5000; tiles *= 1.7) {
    EXPECT_LE(autoTileTasksAhead(tiles, 2), autoTileTasksAhead(tiles * 1.7, 2));
    EXPECT_GE(autoTileTasksAhead(tiles, 2), autoTileTasksAhead(tiles, 3));
  }
  EXPECT_EQ(parseTileTasksAhead("auto"), 0u);
  EXPECT_EQ(parseTileTasksAhead("1"), 1u);
  EXPECT_EQ(parseTileTasksAhead("64"), 64u);
  for (const char* bad : {"0", "65", "-1", "two", "", "3x"}) {
    EXPECT_THROW(parseTileTasksAhead(bad), UsageError) << bad;
  }
  v1::RunSettings settings;
  EXPECT_EQ(tileTasksAhead(settings), kDefaultTileTasksAhead);
  settings.set_tile_tasks_ahead(6);
  EXPECT_EQ(tileTasksAhead(settings), 6u);
}

TEST(RunSettings, RenderCoreShareIsAutoOrAShareAboveZeroUpToOne) {
  EXPECT_EQ(parseRenderCoreShare("auto"), 0.0f);
  EXPECT_EQ(parseRenderCoreShare("1"), 1.0f);
  EXPECT_EQ(parseRenderCoreShare("0.25"), 0.25f);
  for (const char* bad : {"0", "1.5", "-0.5", "nan", "", "half", "0.5x"}) {
    EXPECT_THROW(parseRenderCoreShare(bad), UsageError) << bad;
  }
}

// --need-gap: auto leaves the choice to the handshake; a number, 0 included
// (the drawn ranges alone), is the run's gap; unset counts as over links.
TEST(RunSettings, NeedGapIsAutoOrACountAndUnsetMeansTheCopiedGap) {
  EXPECT_EQ(parseNeedGapSplats("auto"), std::nullopt);
  EXPECT_EQ(parseNeedGapSplats("0"), 0u);
  EXPECT_EQ(parseNeedGapSplats("300"), 300u);
  for (const char* bad : {"", "-1", "65537", "8x", "many"}) {
    EXPECT_THROW(parseNeedGapSplats(bad), UsageError) << bad;
  }
  v1::RunSettings settings;
  EXPECT_EQ(needGapSplats(settings), kNeedGapSplatsCopied);
  settings.set_need_gap_splats(0);
  EXPECT_EQ(needGapSplats(settings), 0u);
  settings.set_need_gap_splats(kNeedGapSplatsInPlace);
  EXPECT_EQ(needGapSplats(settings), kNeedGapSplatsInPlace);
}

}  // namespace
}  // namespace pointillist
