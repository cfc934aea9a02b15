#pragma once
// Liveness of a job's processes, without MPI. Every process and the display
// send each other a Heartbeat at a fixed interval; any message counts as a
// sign of life. A peer silent past the timeout is lost, reported once, and
// stays lost: its state elsewhere (caches, queues) has been dropped, so a
// process that speaks again is not taken back.
//
// Open MPI run with `mpirun --enable-recovery` (deploy/run.sh does) keeps the
// survivors of a lost process running and their point-to-point messages
// flowing, but tells them nothing: sends to the lost process just never
// complete (TCP) or vanish (shared memory). Silence is the signal we have.
#include <chrono>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/clock.hpp"
#include "pointillist.pb.h"

namespace pointillist {

struct LivenessSettings {
  std::chrono::milliseconds heartbeat{1000};
  // A render process drawing one very large packet on a loaded node must not
  // pass for lost: five heartbeats' worth.
  std::chrono::milliseconds peerTimeout{5000};
};

// "no word from it for 5.0 s"
std::string silenceText(double seconds);

// The run's settings, or the defaults where they are unset (0).
LivenessSettings livenessOf(const v1::RunSettings& settings);
// Writes `liveness` into the run's settings.
void setLiveness(v1::RunSettings& settings, const LivenessSettings& liveness);

class PeerWatch {
 public:
  PeerWatch() = default;
  // Watches `ranks`, all taken as heard from at `now`.
  PeerWatch(const std::vector<int>& ranks, std::chrono::milliseconds timeout, TimePoint now);

  void heard(int rank, TimePoint now);  // ranks not watched are ignored
  // `rank` may be silent this much longer than the timeout (the longest it
  // has been seen busy, e.g. drawing one tile, which sends nothing). Keeps
  // the largest given.
  void allowSilence(int rank, std::chrono::milliseconds extra);
  // Watched peers silent for longer than the timeout that were not reported
  // before, in rank order; from then on they are lost.
  std::vector<int> newlyLost(TimePoint now);
  // Takes `rank` as lost without waiting (it said it is going, or failed).
  void markLost(int rank);
  bool lost(int rank) const;
  bool watching(int rank) const { return peers_.contains(rank); }
  std::vector<int> lostRanks() const;
  // How long `rank` has been silent (0 when not watched).
  double silentSeconds(int rank, TimePoint now) const;
  std::chrono::milliseconds timeout() const { return timeout_; }

 private:
  struct Peer {
    TimePoint lastHeard;
    std::chrono::milliseconds extra{0};
    bool lost = false;
  };
  std::map<int, Peer> peers_;
  std::chrono::milliseconds timeout_{0};
};

// When to send the next heartbeat.
class HeartbeatTimer {
 public:
  HeartbeatTimer() = default;
  HeartbeatTimer(std::chrono::milliseconds interval, TimePoint now)
      : interval_(interval), next_(now + interval) {}
  // True at most once per interval; a late call does not make up for missed ones.
  bool due(TimePoint now) {
    if (interval_.count() <= 0 || now < next_) return false;
    next_ = now + interval_;
    return true;
  }

 private:
  std::chrono::milliseconds interval_{0};
  TimePoint next_{};
};

}  // namespace pointillist
