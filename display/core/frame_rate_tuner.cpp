#include "display/core/frame_rate_tuner.hpp"

#include <algorithm>
#include <cstdio>

namespace pointillist::display {

FrameRateTuner::FrameRateTuner(FrameRateTunerOptions options) : options_(options) {
  options_.trialFrames = std::max<std::uint32_t>(options_.trialFrames, 2);
  options_.settleFrames = std::min(options_.settleFrames, options_.trialFrames - 2);
  warmupUntil_ = options_.warmupFrames;
}

void FrameRateTuner::startTrial(std::uint32_t level, std::uint64_t firstFrame) {
  phase_ = Phase::Trial;
  trialLevel_ = level;
  trialFirst_ = firstFrame;
  trialAdmitted_ = 0;
  trialEnds_.assign(options_.trialFrames, 0.0);
  trialSplit_ = false;
}

void FrameRateTuner::frameAdmitted(std::uint64_t frame, bool mayStart) {
  if (phase_ == Phase::Warmup && frame >= warmupUntil_ && mayStart) {
    measuredBaseline_ = false;
    moved_ = false;
    startTrial(chosen_, frame);
  } else if (phase_ == Phase::Settled && frame >= settledUntil_ && mayStart) {
    measuredBaseline_ = false;  // the view moved on: measure the chosen level again first
    moved_ = false;
    startTrial(chosen_, frame);
  } else if (phase_ == Phase::Trial && trialAdmitted_ == 0) {
    trialFirst_ = frame;  // a trial decided while its predecessor's frames were out
  }
  std::uint32_t level = chosen_;
  if (phase_ == Phase::Trial) {
    level = trialLevel_;
    if (++trialAdmitted_ == options_.trialFrames) phase_ = Phase::Waiting;
  }
  levelOf_[frame] = level;
  nextAdmit_ = frame + 1;
}

std::uint64_t FrameRateTuner::factorFor(std::uint64_t frame) const {
  const auto found = levelOf_.find(frame);
  return found == levelOf_.end() ? 1 : std::uint64_t{1} << found->second;
}

void FrameRateTuner::frameFinished(std::uint64_t frame, double seconds, bool actedOn) {
  levelOf_.erase(frame);
  if (phase_ != Phase::Trial && phase_ != Phase::Waiting) return;
  if (frame < trialFirst_ || frame - trialFirst_ >= trialAdmitted_) return;
  const std::uint64_t index = frame - trialFirst_;
  trialEnds_[index] = seconds;
  trialSplit_ = trialSplit_ || actedOn;
  if (phase_ != Phase::Waiting || index + 1 != options_.trialFrames) return;
  // Frames finish in order: the trial's last is in.
  const double first = trialEnds_[options_.settleFrames];
  const double last = trialEnds_.back();
  const double intervals = static_cast<double>(options_.trialFrames - options_.settleFrames - 1);
  trialMeasured(last > first ? intervals / (last - first) : 0.0, trialSplit_);
}

void FrameRateTuner::trialMeasured(double framesPerSecond, bool actedOn) {
  ++trials_;
  if (actedOn) ++splitTrials_;
  lastRate_[trialLevel_] = framesPerSecond;
  if (measuredBaseline_ && !rechecking_) {
    // A candidate: measure the best level again, and compare the candidate
    // with the mean of the trials before and after it, so a view that grew
    // lighter or heavier along the camera path does not decide.
    candidateLevel_ = trialLevel_;
    candidateRate_ = framesPerSecond;
    rechecking_ = true;
    startTrial(bestLevel_, nextAdmit_);
    return;
  }
  if (rechecking_) {
    rechecking_ = false;
    bestRate_ = 0.5 * (bestRate_ + framesPerSecond);
    trialLevel_ = candidateLevel_;
    framesPerSecond = candidateRate_;
  }
  if (!measuredBaseline_) {
    if (!actedOn) {
      settle();  // the knob acted on nothing at the chosen level
      return;
    }
    measuredBaseline_ = true;
    bestLevel_ = trialLevel_;
    bestRate_ = framesPerSecond;
    goingUp_ = true;
    triedDown_ = false;
    moved_ = false;
    probedFlat_ = false;
  } else if (framesPerSecond > bestRate_ * (1.0 + options_.gain)) {
    bestLevel_ = trialLevel_;
    bestRate_ = framesPerSecond;
    chosen_ = bestLevel_;  // frames between trials get it at once
    moved_ = true;
  } else if (goingUp_ && !probedFlat_ && trialLevel_ < topLevel() &&
             framesPerSecond >= bestRate_ * (1.0 - options_.gain)) {
    // A flat step (another limit held the rate): one more before turning back.
    probedFlat_ = true;
    startTrial(trialLevel_ + 1, nextAdmit_);
    return;
  } else if (goingUp_ && !moved_ && !triedDown_ && bestLevel_ > 0) {
    goingUp_ = false;  // larger parts did not pay from here: smaller ones may
    triedDown_ = true;
  } else {
    settle();
    return;
  }
  if (goingUp_ && bestLevel_ < topLevel()) {
    startTrial(bestLevel_ + 1, nextAdmit_);
  } else if (!goingUp_ && bestLevel_ > 0) {
    startTrial(bestLevel_ - 1, nextAdmit_);
  } else if (goingUp_ && !moved_ && !triedDown_ && bestLevel_ > 0) {
    goingUp_ = false;
    triedDown_ = true;
    startTrial(bestLevel_ - 1, nextAdmit_);
  } else {
    settle();
  }
}

void FrameRateTuner::settle() {
  if (measuredBaseline_) chosen_ = bestLevel_;
  phase_ = Phase::Settled;
  // A round that kept its level waits twice as long for the next (up to 8
  // times `settledFrames`): trials of worse levels cost frames, and a view
  // that changes little needs few of them.
  const std::uint64_t base = std::max<std::uint64_t>(1, options_.settledFrames);
  settledPeriod_ = moved_ ? base : std::min(base * 8, std::max(base, settledPeriod_ * 2));
  settledUntil_ = nextAdmit_ + settledPeriod_;
}

std::string FrameRateTuner::summary() const {
  if (trials_ == 0) return {};
  char item[80];
  if (splitTrials_ == 0) {
    std::snprintf(item, sizeof item, "x%llu, not tuned: no tile was split (%u trial%s)",
                  static_cast<unsigned long long>(factor()), trials_, trials_ == 1 ? "" : "s");
    return item;
  }
  const auto times = [](std::uint64_t f) {
    char text[32];
    std::snprintf(text, sizeof text, "x%llu ", static_cast<unsigned long long>(f));
    return std::string(text);
  };
  std::string text = "sized " + times(factor());
  text += "by the frame rate (";
  text += ratesText(times);
  text += ')';
  return text;
}

std::string FrameRateTuner::ratesText(const std::function<std::string(std::uint64_t)>& name) const {
  std::string text;
  char rate[32];
  for (const auto& [level, framesPerSecond] : lastRate_) {
    std::snprintf(rate, sizeof rate, "%.1f", framesPerSecond);
    if (!text.empty()) text += ", ";
    text += name(std::uint64_t{1} << level);
    text += rate;
  }
  std::snprintf(rate, sizeof rate, " frames/s; %u trial%s", trials_, trials_ == 1 ? "" : "s");
  return text + rate;
}

}  // namespace pointillist::display
