#pragma once
// A knob of the display's plan tuned on the frame rate it sees
// (docs/scheduling.md §23): level 0 is the plan as its options give it,
// level k scales the knob by 2^k. The display tunes two of them:
// - the part size of split tiles: a heavy tile too small to halve is split
//   into parts of one render's share of a frame (TilePlanner::partSplats);
//   past a few hundred render processes that share is small, every part
//   sends an image of about its tile's drawn pixels, and the display's
//   link, its CPU or the traverse processes fill while the renders idle;
// - the tile count, divided by the factor: every tile is a walk for a
//   traverse process, and 2 tiles per render process at R = 1024 is more
//   walks than 8 traverse processes make, while parts already spread a
//   heavy tile over several renders.
// Which level pays depends on the scene, the frame size, the links and the
// layout, so the display measures it: it plans a few frames at the next
// level, then a few at the best one again, and compares the candidate with
// the mean of the trials around it (the view moves along the camera path);
// it keeps the next level while the frame rate rises by more than `gain`
// (past one level that is no faster and no slower, once a round: another
// limit may hold the rate until the knob moves further), tries lower ones
// back when it did not, and tries again every `settledFrames` frames, since
// the view changes. Two tuners take turns (`mayStart`), so neither
// measures while the other's trial moves the rate.
//
// The level a frame gets is fixed when the frame is admitted; frames
// finish in order. Deterministic for the same completion times. MPI-free.
#include <algorithm>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace pointillist::display {

struct FrameRateTunerOptions {
  // Frames a trial of one size plans; the rate is measured over the last
  // ones of them, after `settleFrames` for the pipeline and the caches:
  // frames in flight were planned with the size before, and parts of a new
  // size go to other renders, whose data moves over the first frames.
  std::uint32_t trialFrames = 24;
  std::uint32_t settleFrames = 8;
  // Frames before the first trial: cold caches and the first measured plan
  // (a baseline measured while the caches fill looks slow beside anything
  // measured after it).
  std::uint32_t warmupFrames = 16;
  // Largest factor tried is 2^maxLevel.
  std::uint32_t maxLevel = 4;
  // A larger or smaller size is kept only when it is this much faster: frames
  // finish in bursts (several in flight), and 16 of them measure a rate to
  // a few percent at best.
  double gain = 0.10;
  // Frames planned with the chosen level before the levels are tried again;
  // twice as many after each round that kept its level, up to 8 times.
  std::uint32_t settledFrames = 64;
};

class FrameRateTuner {
 public:
  explicit FrameRateTuner(FrameRateTunerOptions options = {});

  // Frame `frame` enters the window: its factor is fixed from now on.
  // Frames are admitted in increasing order. A trial due begins only where
  // `mayStart` (the other tuner is not measuring); else it waits.
  void frameAdmitted(std::uint64_t frame, bool mayStart = true);
  // The factor (1, 2, 4, ...) of an admitted frame; 1 for one not admitted.
  std::uint64_t factorFor(std::uint64_t frame) const;
  // An admitted frame finished at `seconds` (any clock, increasing);
  // `actedOn`: the knob had something to act on in it (for the part size:
  // some tile was split). A trial none of whose frames it acted on is not
  // compared: the level changed nothing.
  void frameFinished(std::uint64_t frame, double seconds, bool actedOn = true);
  // A trial is planned or its frames are still out.
  bool measuring() const { return phase_ == Phase::Trial || phase_ == Phase::Waiting; }

  std::uint64_t factor() const { return std::uint64_t{1} << chosen_; }  // the chosen one
  // No trial above `level` from now on (the caller knows a higher one cannot
  // pay); the chosen level stays until a round finds a better one.
  void setLevelCap(std::uint32_t level) { levelCap_ = level; }
  std::uint32_t topLevel() const { return std::min(options_.maxLevel, levelCap_); }
  // The factor, each one tried and the last frame rate measured with it,
  // e.g. "sized x2 by the frame rate (x1 412.3, x2 466.1, x4 450.0 frames/s;
  // 3 trials)", or "x1, not tuned: no tile was split (1 trial)" where the
  // trials had nothing to act on; empty before any trial. For the part size.
  std::string summary() const;
  // The rates of summary(), each level named by `name(factor)`:
  // "x1 412.3, x2 466.1 frames/s; 3 trials".
  std::string ratesText(const std::function<std::string(std::uint64_t)>& name) const;
  std::uint32_t trials() const { return trials_; }
  std::uint32_t trialsActedOn() const { return splitTrials_; }

 private:
  enum class Phase { Warmup, Trial, Waiting, Settled };
  void startTrial(std::uint32_t level, std::uint64_t firstFrame);
  void trialMeasured(double framesPerSecond, bool actedOn);
  void settle();

  FrameRateTunerOptions options_;
  Phase phase_ = Phase::Warmup;
  std::uint32_t chosen_ = 0;  // level of the size frames get outside trials
  std::uint32_t levelCap_ = ~std::uint32_t{0};
  // The trial planned or being measured.
  std::uint32_t trialLevel_ = 0;
  std::uint64_t trialFirst_ = 0;
  std::uint32_t trialAdmitted_ = 0;
  std::vector<double> trialEnds_;
  bool trialSplit_ = false;
  // This round of trials: the best level and its rate, the direction tried.
  std::uint32_t bestLevel_ = 0;
  double bestRate_ = 0.0;
  bool measuredBaseline_ = false;
  bool goingUp_ = true;
  bool triedDown_ = false;
  bool moved_ = false;       // this round kept a level other than its first
  bool probedFlat_ = false;  // this round went on past a level no faster and no slower
  // A candidate measured, the best level being measured again.
  bool rechecking_ = false;
  std::uint32_t candidateLevel_ = 0;
  double candidateRate_ = 0.0;
  std::uint64_t nextAdmit_ = 0;
  std::uint64_t settledUntil_ = 0;  // Settled: the next trial starts with this frame
  std::uint64_t settledPeriod_ = 0;
  std::uint64_t warmupUntil_ = 0;
  std::map<std::uint64_t, std::uint32_t> levelOf_;  // admitted frames not finished
  std::map<std::uint32_t, double> lastRate_;        // by level
  std::uint32_t trials_ = 0;
  std::uint32_t splitTrials_ = 0;  // trials the knob acted on
};

}  // namespace pointillist::display
