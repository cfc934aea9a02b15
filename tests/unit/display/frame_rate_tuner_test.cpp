// The display's frame-rate tuner (part size, tile count): it keeps the
// factor whose frames come fastest, leaves the knob alone where it acts on
// nothing, measures again when the view changes, never changes a frame's
// factor once it is admitted, and two of them take turns.
#include "display/core/frame_rate_tuner.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <functional>
#include <map>
#include <utility>
#include <vector>

namespace pointillist::display {
namespace {

// A job whose frames take `interval(frame, factor)` seconds each, one after
// the other, with `inFlight` frames admitted at a time (frame f enters as
// frame f - inFlight finishes), as FrameAssembly drives the tuner.
struct PipelineRun {
  std::vector<std::uint64_t> factors;  // by frame, as admitted
  double seconds = 0.0;
};

PipelineRun runPipeline(FrameRateTuner& tuner, std::uint64_t frames,
                        const std::function<double(std::uint64_t, std::uint64_t)>& interval,
                        bool split = true, std::uint32_t inFlight = 3) {
  PipelineRun run;
  std::uint64_t admitted = 0;
  const auto admitUpTo = [&](std::uint64_t end) {
    for (; admitted < std::min(end, frames); ++admitted) {
      tuner.frameAdmitted(admitted);
      run.factors.push_back(tuner.factorFor(admitted));
    }
  };
  admitUpTo(inFlight);
  for (std::uint64_t f = 0; f < frames; ++f) {
    run.seconds += interval(f, run.factors.at(f));
    EXPECT_EQ(tuner.factorFor(f), run.factors[f]) << "frame " << f << " changed its factor";
    tuner.frameFinished(f, run.seconds, split);
    admitUpTo(f + 1 + inFlight);
  }
  return run;
}

// Trials of 8 frames measured over their last 5, after 3 frames of warm-up,
// kept when 3 % faster: the frame counts and rates below are for these,
// whatever the defaults are.
FrameRateTunerOptions shortTrials() {
  FrameRateTunerOptions options;
  options.trialFrames = 8;
  options.settleFrames = 3;
  options.warmupFrames = 3;
  options.gain = 0.03;
  return options;
}

// Frames per second by factor, the same for every frame.
std::function<double(std::uint64_t, std::uint64_t)> rates(std::map<std::uint64_t, double> fps) {
  return [fps](std::uint64_t, std::uint64_t factor) { return 1.0 / fps.at(factor); };
}

TEST(FrameRateTuner, KeepsTheFactorWhoseFramesComeFastest) {
  FrameRateTuner tuner(shortTrials());
  const PipelineRun run =
      runPipeline(tuner, 100, rates({{1, 100}, {2, 150}, {4, 200}, {8, 190}, {16, 180}}));
  EXPECT_EQ(tuner.factor(), 4u);
  // Baseline, then x2, x4 and x8 each followed by the best again; x8 not
  // kept; later frames all at x4 until the levels are tried again.
  EXPECT_EQ(tuner.trials(), 7u);
  for (std::uint64_t f = 75; f < 100; ++f) EXPECT_EQ(run.factors[f], 4u) << "frame " << f;
  EXPECT_EQ(run.factors[0], 1u);
  const std::string summary = tuner.summary();
  EXPECT_EQ(summary.rfind("sized x4 by the frame rate (", 0), 0u) << summary;
  EXPECT_NE(summary.find("x1 100.0"), std::string::npos) << summary;
  EXPECT_NE(summary.find("x4 200.0"), std::string::npos) << summary;
}

TEST(FrameRateTuner, GoesBackWhenLargerPartsAreSlower) {
  FrameRateTuner tuner(shortTrials());
  const PipelineRun run = runPipeline(tuner, 60, rates({{1, 300}, {2, 250}, {4, 200}}));
  EXPECT_EQ(tuner.factor(), 1u);
  EXPECT_EQ(tuner.trials(), 3u);  // the baseline, one of x2 and the baseline again
  std::uint64_t atTwo = 0;
  for (const std::uint64_t factor : run.factors) atTwo += factor == 2;
  EXPECT_EQ(atTwo, shortTrials().trialFrames);  // one trial's frames, no more
  for (std::uint64_t f = 30; f < 60; ++f) EXPECT_EQ(run.factors[f], 1u) << "frame " << f;
}

TEST(FrameRateTuner, SmallGainsDoNotMoveIt) {
  FrameRateTuner tuner(shortTrials());  // gain 3 %
  runPipeline(tuner, 60, rates({{1, 100}, {2, 101}, {4, 102}, {8, 102}}));
  EXPECT_EQ(tuner.factor(), 1u);
}

// A step no faster and no slower is passed once a round: the rate was held
// by another limit until the knob moved further.
TEST(FrameRateTuner, GoesOnPastOneFlatStep) {
  FrameRateTuner tuner(shortTrials());
  runPipeline(tuner, 60, rates({{1, 100}, {2, 100}, {4, 150}, {8, 140}, {16, 140}}));
  EXPECT_EQ(tuner.factor(), 4u);
  FrameRateTuner twoFlat(shortTrials());
  runPipeline(twoFlat, 60, rates({{1, 100}, {2, 100}, {4, 100}, {8, 150}}));
  EXPECT_EQ(twoFlat.factor(), 1u);
}

TEST(FrameRateTuner, LeavesTheSizeAloneWhereNothingIsSplit) {
  FrameRateTuner tuner(shortTrials());
  const PipelineRun run = runPipeline(tuner, 40, rates({{1, 100}, {2, 200}}), /*split=*/false);
  EXPECT_EQ(tuner.factor(), 1u);
  EXPECT_EQ(tuner.trials(), 1u);
  for (const std::uint64_t factor : run.factors) EXPECT_EQ(factor, 1u);
  EXPECT_EQ(tuner.summary(), "x1, not tuned: no tile was split (1 trial)");
}

TEST(FrameRateTuner, TriesAgainWhenTheViewChanges) {
  FrameRateTunerOptions options = shortTrials();
  options.settledFrames = 16;
  FrameRateTuner tuner(options);
  // Large parts pay for the first 150 frames, small ones after.
  const auto interval = [](std::uint64_t frame, std::uint64_t factor) {
    const std::map<std::uint64_t, double> early{{1, 100}, {2, 150}, {4, 200}, {8, 150}};
    const std::map<std::uint64_t, double> late{{1, 300}, {2, 250}, {4, 200}, {8, 150}};
    return 1.0 / (frame < 150 ? early : late).at(factor);
  };
  const PipelineRun run = runPipeline(tuner, 400, interval);
  EXPECT_EQ(run.factors[145], 4u);
  EXPECT_EQ(tuner.factor(), 1u);
  for (std::uint64_t f = 340; f < 400; ++f) EXPECT_LE(run.factors[f], 2u) << "frame " << f;
}

TEST(FrameRateTuner, StopsAtTheLargestFactor) {
  FrameRateTunerOptions options = shortTrials();
  options.maxLevel = 2;
  FrameRateTuner tuner(options);
  const PipelineRun run = runPipeline(tuner, 80, rates({{1, 100}, {2, 200}, {4, 400}}));
  EXPECT_EQ(tuner.factor(), 4u);
  for (const std::uint64_t factor : run.factors) EXPECT_LE(factor, 4u);
}

// Rounds that keep the level come further apart (twice each time, up to 8
// times settledFrames): trials of worse levels cost frames.
TEST(FrameRateTuner, RoundsThatKeepTheLevelComeFurtherApart) {
  FrameRateTunerOptions options = shortTrials();
  options.settledFrames = 16;
  FrameRateTuner tuner(options);
  const PipelineRun run = runPipeline(tuner, 3000, rates({{1, 300}, {2, 250}}));
  std::vector<std::uint64_t> trialStarts;  // first frame of each run of x2
  for (std::size_t f = 1; f < run.factors.size(); ++f) {
    if (run.factors[f] == 2 && run.factors[f - 1] == 1) trialStarts.push_back(f);
  }
  ASSERT_GE(trialStarts.size(), 6u);
  std::vector<std::uint64_t> gaps;
  for (std::size_t i = 1; i < trialStarts.size(); ++i) {
    gaps.push_back(trialStarts[i] - trialStarts[i - 1]);
  }
  for (std::size_t i = 1; i < gaps.size(); ++i) EXPECT_GE(gaps[i], gaps[i - 1]) << "round " << i;
  EXPECT_GT(gaps.back(), 8u * 16u);  // the longest wait, besides the round's own trials
  EXPECT_LT(gaps.back(), 8u * 16u + 4u * 8u);
  EXPECT_EQ(tuner.factor(), 1u);
}

// Two tuners take turns: while one measures, the other starts no trial, so
// neither sees a rate the other's trial moved; both still finish.
TEST(FrameRateTuner, TwoTunersTakeTurns) {
  FrameRateTuner tiles(shortTrials());
  FrameRateTuner parts(shortTrials());
  const std::map<std::uint64_t, double> byTiles{{1, 100}, {2, 150}, {4, 140}};
  const std::map<std::uint64_t, double> byParts{{1, 1.0}, {2, 1.2}, {4, 1.0}};
  double now = 0.0;
  std::uint64_t admitted = 0;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> factors;
  const auto admitUpTo = [&](std::uint64_t end) {
    for (; admitted < end; ++admitted) {
      tiles.frameAdmitted(admitted, !parts.measuring());
      parts.frameAdmitted(admitted, !tiles.measuring());
      EXPECT_FALSE(tiles.measuring() && parts.measuring()) << "frame " << admitted;
      factors.emplace_back(tiles.factorFor(admitted), parts.factorFor(admitted));
    }
  };
  admitUpTo(3);
  for (std::uint64_t f = 0; f < 200; ++f) {
    const auto [tileFactor, partFactor] = factors.at(f);
    now += 1.0 / (byTiles.at(tileFactor) * byParts.at(partFactor));
    tiles.frameFinished(f, now);
    parts.frameFinished(f, now);
    admitUpTo(f + 4);
  }
  EXPECT_EQ(tiles.factor(), 2u);
  EXPECT_EQ(parts.factor(), 2u);
  EXPECT_GE(parts.trials(), 2u);
}

TEST(FrameRateTuner, AFrameNotAdmittedHasFactorOne) {
  FrameRateTuner tuner;
  EXPECT_EQ(tuner.factorFor(7), 1u);
  EXPECT_TRUE(tuner.summary().empty());
}

}  // namespace
}  // namespace pointillist::display
