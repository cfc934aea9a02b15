// The statistical node format (seed 004 §5): packing, the frame, mean and
// colour codes and their error bounds, relative coding of children, packets.
#include "common/statistical_node.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <random>

#include "common/errors.hpp"

namespace pointillist {
namespace {

constexpr double kPi = std::numbers::pi;
using Axes = std::array<std::array<double, 3>, 3>;

std::array<double, 3> cross(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double dot(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
double dotf(const std::array<float, 3>& a, const std::array<double, 3>& b) {
  return double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2];
}

// A random right-handed orthonormal frame (rows).
Axes randomFrame(std::mt19937_64& rng) {
  std::normal_distribution<double> n;
  std::array<double, 3> a{n(rng), n(rng), n(rng)}, b{n(rng), n(rng), n(rng)};
  const double la = std::sqrt(dot(a, a));
  for (double& v : a) v /= la;
  const double p = dot(a, b);
  for (std::size_t k = 0; k < 3; ++k) b[k] -= p * a[k];
  const double lb = std::sqrt(dot(b, b));
  for (double& v : b) v /= lb;
  return {a, b, cross(a, b)};
}

ClassTables someTables() {
  ClassTables t;
  t.position = {{1.0f, 0.5f, 0.01f}, {0.6f, 0.4f, 0.05f}, {0.3f, 0.3f, 0.3f}};
  t.normal = {{0.1f, 0.05f}, {0.5f, 0.2f}};
  t.color = {{10.0f, 5.0f, 1.0f}, {1.0f, 1.0f, 1.0f}};
  return t;
}

StatisticalPacketHeader someHeader(std::uint32_t nodes) {
  StatisticalPacketHeader h{};
  h.magic = kStatisticalMagic;
  h.version = kStatisticalVersion;
  h.nodeCount = nodes;
  h.pointCount = 100;
  h.origin[0] = -1.0f;
  h.origin[1] = 2.0f;
  h.origin[2] = 0.5f;
  h.extent[0] = 4.0f;
  h.extent[1] = 2.0f;
  h.extent[2] = 1.0f;
  return h;
}

TEST(StatisticalNode, PackingKeepsEveryFieldAtItsWidth) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 2000; ++trial) {
    const auto bits = [&](unsigned width) {
      return static_cast<std::uint16_t>(rng() & ((1u << width) - 1u));
    };
    StatisticalNodeCode c;
    c.mean[0] = bits(11);
    c.mean[1] = bits(11);
    c.mean[2] = bits(10);
    c.frame[0] = bits(8);
    c.frame[1] = bits(10);
    c.frame[2] = bits(6);
    c.sigmaClass = bits(12);
    c.normalClass = bits(12);
    c.normalFrame[0] = bits(8);
    c.normalFrame[1] = bits(10);
    c.normalFrame[2] = bits(6);
    c.color565 = bits(16);
    c.colorFrame[0] = bits(4);
    c.colorFrame[1] = bits(3);
    c.colorFrame[2] = bits(3);
    c.colorClass = static_cast<std::uint8_t>(bits(6));
    c.flags = static_cast<std::uint8_t>(bits(8));
    std::byte bytes[kStatisticalNodeBytes + 1];
    bytes[kStatisticalNodeBytes] = std::byte{0xAB};  // the packing stays in its 18 bytes
    packStatisticalNode(c, bytes);
    EXPECT_EQ(bytes[kStatisticalNodeBytes], std::byte{0xAB});
    EXPECT_EQ(unpackStatisticalNode(bytes), c);
  }
}

// The stated error of the frame codes: f3 within half a theta step plus half a
// phi step (scaled by sin theta), f1 within that plus half a psi step.
TEST(StatisticalNode, FramesDecodeWithinTheirQuantizationError) {
  std::mt19937_64 rng(7);
  struct Kind {
    FrameKind kind;
    double thetaStep, phiStep, psiStep;
    bool hemisphere;
  };
  const Kind kinds[] = {{FrameKind::Position, kPi / 2 / 255, 2 * kPi / 1024, kPi / 64, true},
                        {FrameKind::Normal, kPi / 255, 2 * kPi / 1024, kPi / 64, false},
                        {FrameKind::Color, kPi / 2 / 15, 2 * kPi / 8, kPi / 8, true}};
  for (const Kind& k : kinds) {
    double worstAxis = 0, worstMajor = 0;
    for (int trial = 0; trial < 3000; ++trial) {
      const Axes axes = randomFrame(rng);
      std::uint16_t code[3];
      encodeFrame(k.kind, axes, code);
      const auto f = decodeFrame(k.kind, code);
      // Orthonormal and right-handed.
      for (std::size_t i = 0; i < 3; ++i) {
        std::array<double, 3> fi{f[i][0], f[i][1], f[i][2]};
        EXPECT_NEAR(dot(fi, fi), 1.0, 1e-5);
      }
      std::array<double, 3> f0{f[0][0], f[0][1], f[0][2]}, f1{f[1][0], f[1][1], f[1][2]};
      const auto c = cross(f0, f1);
      EXPECT_NEAR(dotf(f[2], c), 1.0, 1e-5);
      // The smallest axis (a Gaussian's axes are sign-free; the normal's is not).
      const double d3 = dotf(f[2], axes[2]);
      const double a3 = std::acos(std::min(1.0, k.hemisphere ? std::abs(d3) : d3));
      const double a1 = std::acos(std::min(1.0, std::abs(dotf(f[0], axes[0]))));
      worstAxis = std::max(worstAxis, a3);
      worstMajor = std::max(worstMajor, a1);
    }
    const double axisBound = k.thetaStep / 2 + k.phiStep / 2 + 1e-6;
    EXPECT_LE(worstAxis, axisBound) << static_cast<int>(k.kind);
    // psi is measured in the decoded plane, which the axis error tilts.
    EXPECT_LE(worstMajor, axisBound + k.psiStep / 2 + 1e-6) << static_cast<int>(k.kind);
  }
}

TEST(StatisticalNode, RootMeanDecodesWithinHalfAStepOfTheCellBox) {
  const StatisticalPacketHeader h = someHeader(1);
  const ClassTables tables = someTables();
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 1000; ++trial) {
    double mean[3];
    for (std::size_t k = 0; k < 3; ++k)
      mean[k] = double(h.origin[k]) + u(rng) * double(h.extent[k]);
    StatisticalNodeCode code;
    encodeNodeMean(mean, nullptr, h, code.mean);
    const StatisticalNode n = decodeStatisticalNode(code, nullptr, h, tables);
    const double levels[3] = {2047, 2047, 1023};
    for (std::size_t k = 0; k < 3; ++k)
      EXPECT_LE(std::abs(double(n.mean[k]) - mean[k]), double(h.extent[k]) / levels[k] / 2 + 1e-6);
  }
}

// Children are coded in their parent's frame and spread: the error along each
// parent axis is at most half a step of kChildMeanRange * sigma_k, and the
// same code under another parent is another point.
TEST(StatisticalNode, ChildMeansAreCodedRelativeToTheDecodedParent) {
  const StatisticalPacketHeader h = someHeader(3);
  const ClassTables tables = someTables();
  std::mt19937_64 rng(5);
  std::normal_distribution<double> n;
  for (int trial = 0; trial < 500; ++trial) {
    StatisticalNodeCode parentCode;
    const double parentMean[3] = {0.5, 2.5, 1.0};
    encodeNodeMean(parentMean, nullptr, h, parentCode.mean);
    encodeFrame(FrameKind::Position, randomFrame(rng), parentCode.frame);
    parentCode.sigmaClass = static_cast<std::uint16_t>(trial % 3);
    const StatisticalNode parent = decodeStatisticalNode(parentCode, nullptr, h, tables);
    // A child mean a couple of sigmas away along the parent's axes.
    double child[3];
    double along[3];
    for (std::size_t k = 0; k < 3; ++k) along[k] = 2.0 * n(rng) * double(parent.sigma[k]);
    for (std::size_t j = 0; j < 3; ++j) {
      child[j] = double(parent.mean[j]);
      for (std::size_t k = 0; k < 3; ++k) child[j] += along[k] * double(parent.axes[k][j]);
    }
    StatisticalNodeCode code;
    encodeNodeMean(child, &parent, h, code.mean);
    const StatisticalNode decoded = decodeStatisticalNode(code, &parent, h, tables);
    const double levels[3] = {2047, 2047, 1023};
    for (std::size_t k = 0; k < 3; ++k) {
      double d = 0;
      for (std::size_t j = 0; j < 3; ++j)
        d += (double(decoded.mean[j]) - child[j]) * double(parent.axes[k][j]);
      const double s = std::max(double(parent.sigma[k]), double(kMeanRangeFloor * parent.sigma[0]));
      EXPECT_LE(std::abs(d), double(kChildMeanRange) * s / levels[k] + 1e-5) << k;
    }
    // Position sigmas are ratios to the parent's largest.
    EXPECT_FLOAT_EQ(decoded.sigma[0], tables.position[code.sigmaClass][0] * parent.sigma[0]);
    // The same code decoded under another parent moves with it.
    StatisticalNode moved = parent;
    moved.mean[0] += 1.0f;
    const StatisticalNode shifted = decodeStatisticalNode(code, &moved, h, tables);
    EXPECT_NEAR(shifted.mean[0], decoded.mean[0] + 1.0f, 1e-5);
  }
}

TEST(StatisticalNode, Color565RoundsToTheNearestLevel) {
  for (int v = 0; v <= 255; v += 5) {
    const double rgb[3] = {double(v), double(v), double(255 - v)};
    StatisticalNodeCode code;
    code.color565 = encodeColor565(rgb);
    const StatisticalNode n = decodeStatisticalNode(code, nullptr, someHeader(1), someTables());
    EXPECT_LE(std::abs(double(n.color[0]) - rgb[0]), 255.0 / 31 / 2 + 1e-4);
    EXPECT_LE(std::abs(double(n.color[1]) - rgb[1]), 255.0 / 63 / 2 + 1e-4);
    EXPECT_LE(std::abs(double(n.color[2]) - rgb[2]), 255.0 / 31 / 2 + 1e-4);
  }
}

// A root with two children, the left one with two more: five nodes.
std::vector<std::byte> fiveNodePacket(const ClassTables& tables) {
  const StatisticalPacketHeader h = someHeader(5);
  std::vector<std::byte> bytes((kStatisticalHeaderBytes + 5 * kStatisticalNodeBytes + 31) / 32 *
                               32);
  std::memcpy(bytes.data(), &h, sizeof h);
  const std::uint8_t flags[5] = {kNodeHasChildren, kNodeHasChildren, 0, 0, 0};
  for (std::size_t i = 0; i < 5; ++i) {
    StatisticalNodeCode c;
    c.mean[0] = static_cast<std::uint16_t>(1000 + i);
    c.sigmaClass = static_cast<std::uint16_t>(i % tables.position.size());
    c.flags = flags[i];
    packStatisticalNode(c, bytes.data() + kStatisticalHeaderBytes + i * kStatisticalNodeBytes);
  }
  return bytes;
}

TEST(StatisticalNode, PacketsDecodeBreadthFirstAndPrefixesDecodeTheirNodes) {
  const ClassTables tables = someTables();
  const auto bytes = fiveNodePacket(tables);
  const auto view = decodeStatisticalPacket(bytes, tables, "test");
  ASSERT_EQ(view.nodes.size(), 5u);
  EXPECT_EQ(view.nodes[0].firstChild, 1u);
  EXPECT_EQ(view.nodes[1].firstChild, 3u);
  EXPECT_EQ(view.nodes[2].firstChild, 0u);
  EXPECT_EQ(view.nodes[3].parent, 1u);
  EXPECT_EQ(view.nodes[4].parent, 1u);
  EXPECT_EQ(view.nodes[2].parent, 0u);
  // A prefix of whole records decodes its complete nodes identically.
  const std::uint32_t records = statisticalPrefixRecords(3);
  EXPECT_EQ(statisticalNodesInRecords(records, 5), 3u);
  const auto prefix = decodeStatisticalPacket(
      std::span<const std::byte>(bytes).first(std::size_t{records} * 32), tables, "test");
  ASSERT_EQ(prefix.nodes.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i)
    EXPECT_EQ(std::memcmp(&prefix.nodes[i], &view.nodes[i], sizeof(StatisticalNode)), 0);
}

// A render process holds a prefix and receives more: decoding goes on where
// it stopped and gives the nodes a whole decode gives.
TEST(StatisticalNode, LongerPrefixesExtendWhatWasDecoded) {
  const ClassTables tables = someTables();
  const auto bytes = fiveNodePacket(tables);
  const auto whole = decodeStatisticalPacket(bytes, tables, "test");
  StatisticalPacketView view;
  for (std::uint32_t nodes : {1u, 2u, 2u, 4u, 5u}) {
    const std::size_t records = statisticalPrefixRecords(nodes);
    extendStatisticalPacket(view, std::span<const std::byte>(bytes).first(records * 32), tables,
                            "test");
    ASSERT_GE(view.nodes.size(), nodes);
  }
  ASSERT_EQ(view.nodes.size(), whole.nodes.size());
  for (std::size_t i = 0; i < whole.nodes.size(); ++i)
    EXPECT_EQ(std::memcmp(&view.nodes[i], &whole.nodes[i], sizeof(StatisticalNode)), 0) << i;
  // Another packet's bytes are refused.
  auto other = bytes;
  StatisticalPacketHeader h{};
  std::memcpy(&h, other.data(), sizeof h);
  h.origin[0] += 1.0f;
  std::memcpy(other.data(), &h, sizeof h);
  EXPECT_THROW(extendStatisticalPacket(view, other, tables, "test"), InputError);
}

TEST(StatisticalNode, DamagedPacketsAreRefusedWithTheirPlace) {
  const ClassTables tables = someTables();
  const auto good = fiveNodePacket(tables);
  auto badMagic = good;
  badMagic[0] = std::byte{0};
  EXPECT_THROW(decodeStatisticalPacket(badMagic, tables, "cell 7"), InputError);
  // A class outside the tables.
  auto badClass = good;
  StatisticalNodeCode c = unpackStatisticalNode(badClass.data() + kStatisticalHeaderBytes);
  c.sigmaClass = 4000;
  packStatisticalNode(c, badClass.data() + kStatisticalHeaderBytes);
  try {
    decodeStatisticalPacket(badClass, tables, "cell 7");
    FAIL() << "a class outside the tables was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cell 7"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("class"), std::string::npos);
  }
  // Children beyond the node count.
  auto badTree = good;
  for (std::size_t i = 2; i < 5; ++i) {
    StatisticalNodeCode n =
        unpackStatisticalNode(badTree.data() + kStatisticalHeaderBytes + i * kStatisticalNodeBytes);
    n.flags = kNodeHasChildren;
    packStatisticalNode(n, badTree.data() + kStatisticalHeaderBytes + i * kStatisticalNodeBytes);
  }
  EXPECT_THROW(decodeStatisticalPacket(badTree, tables, "cell 7"), InputError);
}

TEST(StatisticalNode, ClassTablesRoundTripAndRefuseDamage) {
  const ClassTables tables = someTables();
  const auto bytes = encodeClassTables(tables);
  const ClassTables back = decodeClassTables(bytes, "classes");
  EXPECT_EQ(back.position, tables.position);
  EXPECT_EQ(back.normal, tables.normal);
  EXPECT_EQ(back.color, tables.color);
  auto shortened = bytes;
  shortened.pop_back();
  EXPECT_THROW(decodeClassTables(shortened, "classes"), InputError);
  auto negative = bytes;
  const float minus = -1.0f;
  std::memcpy(negative.data() + 16, &minus, sizeof minus);
  EXPECT_THROW(decodeClassTables(negative, "classes"), InputError);
}

}  // namespace
}  // namespace pointillist
