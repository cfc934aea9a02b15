#include "common/peer_watch.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace pointillist {
namespace {

std::chrono::milliseconds millisecondsOf(float seconds, std::chrono::milliseconds fallback) {
  if (!(seconds > 0.0f)) return fallback;
  return std::chrono::milliseconds(static_cast<long>(std::lround(seconds * 1000.0f)));
}

}  // namespace

std::string silenceText(double seconds) {
  char text[64];
  std::snprintf(text, sizeof text, "no word from it for %.1f s", seconds);
  return text;
}

LivenessSettings livenessOf(const v1::RunSettings& settings) {
  const LivenessSettings defaults;
  return {millisecondsOf(settings.heartbeat_seconds(), defaults.heartbeat),
          millisecondsOf(settings.peer_timeout_seconds(), defaults.peerTimeout)};
}

void setLiveness(v1::RunSettings& settings, const LivenessSettings& liveness) {
  settings.set_heartbeat_seconds(static_cast<float>(liveness.heartbeat.count()) / 1000.0f);
  settings.set_peer_timeout_seconds(static_cast<float>(liveness.peerTimeout.count()) / 1000.0f);
}

PeerWatch::PeerWatch(const std::vector<int>& ranks, std::chrono::milliseconds timeout,
                     TimePoint now)
    : timeout_(timeout) {
  for (int rank : ranks) peers_[rank] = Peer{now, {}, false};
}

void PeerWatch::heard(int rank, TimePoint now) {
  const auto found = peers_.find(rank);
  if (found != peers_.end() && !found->second.lost) {
    found->second.lastHeard = std::max(found->second.lastHeard, now);
  }
}

void PeerWatch::allowSilence(int rank, std::chrono::milliseconds extra) {
  const auto found = peers_.find(rank);
  if (found != peers_.end()) found->second.extra = std::max(found->second.extra, extra);
}

std::vector<int> PeerWatch::newlyLost(TimePoint now) {
  std::vector<int> lost;
  for (auto& [rank, peer] : peers_) {
    if (!peer.lost && now - peer.lastHeard > timeout_ + peer.extra) {
      peer.lost = true;
      lost.push_back(rank);
    }
  }
  return lost;
}

void PeerWatch::markLost(int rank) {
  const auto found = peers_.find(rank);
  if (found != peers_.end()) found->second.lost = true;
}

bool PeerWatch::lost(int rank) const {
  const auto found = peers_.find(rank);
  return found != peers_.end() && found->second.lost;
}

std::vector<int> PeerWatch::lostRanks() const {
  std::vector<int> ranks;
  for (const auto& [rank, peer] : peers_) {
    if (peer.lost) ranks.push_back(rank);
  }
  return ranks;
}

double PeerWatch::silentSeconds(int rank, TimePoint now) const {
  const auto found = peers_.find(rank);
  return found == peers_.end() ? 0.0 : secondsBetween(found->second.lastHeard, now);
}

}  // namespace pointillist
