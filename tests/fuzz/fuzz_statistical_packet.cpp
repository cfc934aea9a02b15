// libFuzzer target: a statistical packet as a render process receives it
// (seed 004; common/statistical_node.hpp), decoded against small class tables
// in two steps and whole, and cut for a camera when it decodes; and the same
// bytes as a class-tables file. An InputError naming the place is the refusal
// damaged bytes should get; anything else is a finding, and so is a two-step
// decode that differs from the whole one.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>

#include "common/camera.hpp"
#include "common/errors.hpp"
#include "common/statistical_cut.hpp"
#include "common/statistical_node.hpp"

namespace {

// Full tables (every class index a packet may name), descending spreads.
const pointillist::ClassTables& tables() {
  static const pointillist::ClassTables t = [] {
    pointillist::ClassTables c;
    for (std::uint32_t i = 0; i < (1u << pointillist::kPositionClassBits); ++i) {
      const float a = 0.3f + 0.7f * float(i % 64) / 63.0f;
      c.position.push_back({a, a * float(i / 64 + 1) / 64.0f, a * 0.01f * float(i % 7 + 1)});
      c.normal.push_back(
          {0.001f + 0.5f * float(i % 97) / 96.0f, 0.001f + 0.2f * float(i % 13) / 12.0f});
    }
    for (std::uint32_t i = 0; i < (1u << pointillist::kColorClassBits); ++i)
      c.color.push_back({float(i) + 1.0f, float(i) * 0.5f, 0.5f});
    return c;
  }();
  return t;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::span<const std::byte> bytes(reinterpret_cast<const std::byte*>(data), size);
  try {
    (void)pointillist::decodeClassTables(bytes, "fuzz/statistical-classes.bin");
  } catch (const pointillist::InputError&) {
  }
  try {
    const auto whole = pointillist::decodeStatisticalPacket(bytes, tables(), "fuzz/packet");
    pointillist::StatisticalPacketView stepwise;
    pointillist::extendStatisticalPacket(stepwise, bytes.first(size / 2 < 64 ? size : size / 2),
                                         tables(), "fuzz/prefix");
    pointillist::extendStatisticalPacket(stepwise, bytes, tables(), "fuzz/packet");
    if (stepwise.nodes.size() != whole.nodes.size()) __builtin_trap();
    for (std::size_t i = 0; i < whole.nodes.size(); ++i)
      if (std::memcmp(&stepwise.nodes[i], &whole.nodes[i], sizeof whole.nodes[i]) != 0)
        __builtin_trap();
    if (whole.nodes.size() == whole.header.nodeCount) {
      const pointillist::StatisticalTrees trees({&whole, 1}, 0);
      const auto camera =
          pointillist::makeCamera({3, -2, 4}, {0, 0, 0}, {0, 0, 1}, 50.0f, 0.01f, 100.0f, 320, 200);
      const auto cut = pointillist::cutStatistical(trees, camera, {});
      (void)pointillist::statisticalTile(trees, cut, camera,
                                         pointillist::makeTileRect(64, 32, 128, 96), {});
    }
  } catch (const pointillist::InputError&) {
  }
  return 0;
}
