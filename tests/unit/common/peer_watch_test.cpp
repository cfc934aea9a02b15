// Liveness without MPI: who is lost, when, and that a busy peer is not.
#include "common/peer_watch.hpp"

#include <gtest/gtest.h>

namespace pointillist {
namespace {

using namespace std::chrono_literals;

const TimePoint kStart = timeAfterEpoch(100.0);

TEST(PeerWatch, APeerSilentPastTheTimeoutIsLostOnceAndStaysLost) {
  PeerWatch watch({1, 2, 3}, 5s, kStart);
  EXPECT_TRUE(watch.newlyLost(kStart + 5s).empty());  // exactly the timeout: not yet
  watch.heard(1, kStart + 4s);
  watch.heard(3, kStart + 4500ms);
  EXPECT_EQ(watch.newlyLost(kStart + 5100ms), std::vector<int>{2});
  EXPECT_TRUE(watch.lost(2));
  EXPECT_DOUBLE_EQ(watch.silentSeconds(2, kStart + 5100ms), 5.1);
  // Reported once; a word from a lost peer does not bring it back.
  watch.heard(2, kStart + 6s);
  EXPECT_TRUE(watch.newlyLost(kStart + 6s).empty());
  EXPECT_TRUE(watch.lost(2));
  EXPECT_EQ(watch.newlyLost(kStart + 9600ms), (std::vector<int>{1, 3}));
  EXPECT_EQ(watch.lostRanks(), (std::vector<int>{1, 2, 3}));
}

TEST(PeerWatch, ALateOrOutOfOrderWordNeverShortensTheSilence) {
  PeerWatch watch({4}, 2s, kStart);
  watch.heard(4, kStart + 3s);
  watch.heard(4, kStart + 1s);  // an older time: ignored
  EXPECT_TRUE(watch.newlyLost(kStart + 4900ms).empty());
  EXPECT_EQ(watch.newlyLost(kStart + 5100ms), std::vector<int>{4});
}

TEST(PeerWatch, ABusyPeerMaySayNothingForTwiceItsLongestWork) {
  PeerWatch watch({4, 5}, 1s, kStart);
  watch.allowSilence(4, 3s);
  watch.allowSilence(4, 1s);  // the largest stays
  EXPECT_EQ(watch.newlyLost(kStart + 1500ms), std::vector<int>{5});
  EXPECT_TRUE(watch.newlyLost(kStart + 3900ms).empty());
  EXPECT_EQ(watch.newlyLost(kStart + 4100ms), std::vector<int>{4});
}

TEST(PeerWatch, RanksNotWatchedAndMarkedLostRanks) {
  PeerWatch watch({1, 2}, 1s, kStart);
  watch.heard(7, kStart + 10s);  // not watched: ignored
  EXPECT_FALSE(watch.watching(7));
  EXPECT_FALSE(watch.lost(7));
  EXPECT_DOUBLE_EQ(watch.silentSeconds(7, kStart + 10s), 0.0);
  watch.markLost(1);  // said it is going: not reported by newlyLost
  EXPECT_TRUE(watch.lost(1));
  EXPECT_EQ(watch.newlyLost(kStart + 2s), std::vector<int>{2});
}

TEST(HeartbeatTimer, DueOncePerIntervalWithoutCatchingUp) {
  HeartbeatTimer timer(1s, kStart);
  EXPECT_FALSE(timer.due(kStart + 999ms));
  EXPECT_TRUE(timer.due(kStart + 1s));
  EXPECT_FALSE(timer.due(kStart + 1500ms));
  // Five intervals late: one beat, then the next a whole interval later.
  EXPECT_TRUE(timer.due(kStart + 7s));
  EXPECT_FALSE(timer.due(kStart + 7500ms));
  EXPECT_TRUE(timer.due(kStart + 8s));
  HeartbeatTimer off;  // no interval: never due
  EXPECT_FALSE(off.due(kStart + 100s));
}

TEST(Liveness, TravelsInTheRunSettingsAndDefaultsWhereUnset) {
  v1::RunSettings settings;
  const LivenessSettings defaults = livenessOf(settings);
  EXPECT_EQ(defaults.heartbeat, 1000ms);
  EXPECT_EQ(defaults.peerTimeout, 5000ms);
  setLiveness(settings, {250ms, 2500ms});
  const LivenessSettings back = livenessOf(settings);
  EXPECT_EQ(back.heartbeat, 250ms);
  EXPECT_EQ(back.peerTimeout, 2500ms);
  EXPECT_EQ(silenceText(5.04), "no word from it for 5.0 s");
}

}  // namespace
}  // namespace pointillist
