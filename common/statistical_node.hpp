#pragma once
// Seed 004's statistical point geometry: a top-level cell's points as a binary
// hierarchy of PCA nodes, each an anisotropic Gaussian of position, normal and
// colour, quantized to 18 bytes (the paper's 13 bytes of position and normal,
// 4 of colour, 1 of flags), written by `pointillist-preprocess --statistical`
// and drawn by the `statistical` render mode, which generates points from the
// nodes of a view-dependent cut (common/statistical_cut.hpp).
//
// Storage. Each top-level cell t has a *statistical packet*: 32-byte records
// in statistical.bin (common/dataset.hpp), addressed like any packet but under
// the packet id topLevelCount + t, so data-send shards, render caches and
// prefixes serve it as they serve the points. Layout, little-endian:
//
//   StatisticalPacketHeader (64 B)
//   nodes, kStatisticalNodeBytes each, breadth-first (node 0 is the root; the
//     children of the j-th node with children are nodes 2j + 1 and 2j + 2)
//   zero padding to a multiple of 32
//
// A prefix of the packet holding nodes [0, k) decodes those nodes: a cut never
// needs more than the nodes up to its deepest one (statisticalPrefixRecords).
//
// Node layout (bits, from byte 0, little-endian bit order within each field):
//   mean       32  11-11-10: the offset from the parent's decoded mean along the
//                  parent's decoded axes f1, f2 (11 bits each) and f3 (10 bits),
//                  each in [-kChildMeanRange, +kChildMeanRange] * parent sigma_k
//                  (sigma_k floored at kMeanRangeFloor * sigma_1); the root's in the
//                  header's box along x, y, z.
//   frame      24  f3 (smallest spread) as theta 8 bits in [0, pi/2] (f3 and -f3
//                  are the same Gaussian) and phi 10 bits in [0, 2 pi); psi 6 bits
//                  in [0, pi): the angle from x' (x rotated like z onto f3) to f1.
//   sigmaClass 12  index into ClassTables::position: sigma / parent's sigma_1
//                  (root: / the header's extent)
//   normalClass12  index into ClassTables::normal (radians)
//   normalFrame24  z = mean normal: theta 8 bits in [0, pi], phi 10 bits, psi 6
//                  bits in [0, pi): x = the major axis of the normals unwrapped
//                  onto the tangent plane (seed 004 §3)
//   color      16  mean RGB 5-6-5
//   colorFrame 10  theta 4, phi 3, psi 3 (as frame)
//   colorClass  6  index into ClassTables::color (RGB units 0..255)
//   flags       8  bit 0: the node has children (they follow, breadth-first)
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "common/splat.hpp"

namespace pointillist {

inline constexpr std::uint32_t kStatisticalMagic = 0x4e535450u;  // "PTSN"
// 2: child means over +-16 sigma, thin axes floored at sigma_1 / 32.
inline constexpr std::uint16_t kStatisticalVersion = 2;
inline constexpr std::size_t kStatisticalNodeBytes = 18;
inline constexpr std::size_t kStatisticalHeaderBytes = 64;
// Generated samples lie within this many standard deviations (seed 004 §6.2:
// gamma = 3.5 holds 99.7 % of the distribution); culling spheres use it too.
inline constexpr float kStatisticalGamma = 3.5f;
// A child's mean lies within this many of its parent's standard deviations
// along each parent axis (a subset holding a share f of the points has its mean
// within sigma * sqrt((1 - f) / f) of the parent's: f >= 1/257 fits, so an
// outlier split off a dense cluster by the Euclidean fallback still does).
inline constexpr float kChildMeanRange = 16.0f;
// The coding range along a thin axis is at least this share of sigma_1: the
// frame's angular quantization (a few tenths of a degree) moves in-plane
// offsets of a flat parent across its normal axis by more than its sigma_3.
inline constexpr float kMeanRangeFloor = 1.0f / 32.0f;
inline constexpr float kSigmaFloor = 1.0f / 1024.0f;
inline constexpr std::uint32_t kPositionClassBits = 12;
inline constexpr std::uint32_t kNormalClassBits = 12;
inline constexpr std::uint32_t kColorClassBits = 6;
inline constexpr std::uint8_t kNodeHasChildren = 1;

struct StatisticalPacketHeader {
  std::uint32_t magic;
  std::uint16_t version;
  std::uint16_t reserved0;
  std::uint32_t nodeCount;
  std::uint32_t pointCount;  // the top-level cell's points the hierarchy stands for
  float origin[3];           // the root mean's box: origin + [0, 1]^3 * extent
  float extent[3];
  std::uint32_t reserved[6];
};
static_assert(sizeof(StatisticalPacketHeader) == kStatisticalHeaderBytes);
static_assert(std::is_trivially_copyable_v<StatisticalPacketHeader>);

// Records of a statistical packet that hold nodes [0, nodes).
inline std::uint32_t statisticalPrefixRecords(std::uint32_t nodes) {
  return static_cast<std::uint32_t>(
      (kStatisticalHeaderBytes + std::uint64_t{nodes} * kStatisticalNodeBytes + 31) / 32);
}
// Complete nodes in a prefix of `records` records (at most nodeCount).
inline std::uint32_t statisticalNodesInRecords(std::uint32_t records, std::uint32_t nodeCount) {
  const std::uint64_t bytes = std::uint64_t{records} * 32;
  if (bytes < kStatisticalHeaderBytes) return 0;
  const std::uint64_t n = (bytes - kStatisticalHeaderBytes) / kStatisticalNodeBytes;
  return n < nodeCount ? static_cast<std::uint32_t>(n) : nodeCount;
}

// The global classification tables (seed 004 §5): the client's start-up
// information. statistical-classes.bin holds them: a 16-byte header (magic
// "PTSC", version, then uint16 counts position, normal, color, reserved), then
// float position[count][3], normal[count][2], color[count][3].
struct ClassTables {
  // sigma_1..3 of a node over its parent's sigma_1 (root: over the header's
  // largest extent), descending.
  std::vector<std::array<float, 3>> position;
  // sigma of the unwrapped normals along the normal frame's x and y, radians.
  std::vector<std::array<float, 2>> normal;
  // sigma of colour along the colour frame's axes, RGB units (0..255).
  std::vector<std::array<float, 3>> color;
};
inline constexpr const char* kStatisticalPacketsKey = "statistical";
inline constexpr const char* kStatisticalPacketsName = "statistical.bin";
inline constexpr const char* kStatisticalIndexKey = "statistical_index";
inline constexpr const char* kStatisticalIndexName = "statistical-index.bin";
inline constexpr const char* kStatisticalClassesKey = "statistical_classes";
inline constexpr const char* kStatisticalClassesName = "statistical-classes.bin";

std::vector<std::byte> encodeClassTables(const ClassTables& tables);
// Throws InputError naming `where` for a bad magic, version, counts above the
// class bits or a size mismatch, and for non-finite or negative values.
ClassTables decodeClassTables(std::span<const std::byte> bytes, const std::string& where);

// statistical-index.bin: one entry per top-level cell, in table order: where
// its statistical packet lies in statistical.bin and its checksum
// (common/checksum.hpp, of the packet's records).
struct StatisticalPacketEntry {
  std::uint64_t byteOffset = 0;
  std::uint32_t records = 0;
  std::uint32_t nodeCount = 0;
  std::uint64_t checksum = 0;
};
static_assert(sizeof(StatisticalPacketEntry) == 24);

// A decoded node: what the cut and the point generation work from. Axes are
// unit and orthogonal; sigma is descending; every generated point is
//   position = mean + sum_k axes[k] * sigma[k] * g[k]
//   normal   = normalFrame[2] cos(theta) + (normalFrame[0] a + normalFrame[1] b) sin(theta) / theta
//              with (a, b) = (sigmaNormal[0] n[0], sigmaNormal[1] n[1]), theta = |(a, b)|
//   color    = clamp(color + sum_k colorAxes[k] * sigmaColor[k] * c[k], 0, 255)
// for a GaussianSample (g, n, c) (common/statistical_samples.hpp).
struct StatisticalNode {
  float mean[3];
  float axes[3][3];
  float sigma[3];
  float normalFrame[3][3];  // [2] is the mean normal
  float sigmaNormal[2];     // radians
  float color[3];           // RGB 0..255
  float colorAxes[3][3];
  float sigmaColor[3];
  std::uint32_t firstChild;  // index of the left child; 0 for a leaf
  std::uint32_t parent;      // index of the parent; 0 for the root
};

// The culling sphere of a node's own generated points: radius gamma * sigma[0].
inline float statisticalNodeRadius(const StatisticalNode& node) {
  return kStatisticalGamma * node.sigma[0];
}

// The quantized fields of one node, as packed into its 18 bytes (see the
// layout above). Frames are (theta, phi, psi) codes.
struct StatisticalNodeCode {
  std::uint16_t mean[3] = {0, 0, 0};   // 11, 11, 10 bits
  std::uint16_t frame[3] = {0, 0, 0};  // 8, 10, 6 bits
  std::uint16_t sigmaClass = 0;
  std::uint16_t normalClass = 0;
  std::uint16_t normalFrame[3] = {0, 0, 0};  // 8, 10, 6 bits
  std::uint16_t color565 = 0;
  std::uint16_t colorFrame[3] = {0, 0, 0};  // 4, 3, 3 bits
  std::uint8_t colorClass = 0;
  std::uint8_t flags = 0;
  bool operator==(const StatisticalNodeCode&) const = default;
};
void packStatisticalNode(const StatisticalNodeCode& code, std::byte* out);  // 18 bytes
StatisticalNodeCode unpackStatisticalNode(const std::byte* in);

// The three frames of a node and their angle codes.
enum class FrameKind {
  Position,  // 8-10-6 bits, f3 on the upper hemisphere
  Normal,    // 8-10-6 bits, z anywhere on the sphere
  Color,     // 4-3-3 bits, f3 on the upper hemisphere
};
// Unit, orthogonal, right-handed axes (rows) of a frame code.
std::array<std::array<float, 3>, 3> decodeFrame(FrameKind kind, const std::uint16_t code[3]);
// The code whose decoded frame is nearest to `axes` (rows, unit, right-handed;
// axes[0] and axes[2] may be negated where the kind allows: a Gaussian is
// symmetric about its axes, the mean normal is not).
void encodeFrame(FrameKind kind, const std::array<std::array<double, 3>, 3>& axes,
                 std::uint16_t code[3]);

// Decodes one node; `parent` is null for the root. Class indices must be
// inside the tables (decodeStatisticalPacket checks them).
StatisticalNode decodeStatisticalNode(const StatisticalNodeCode& code,
                                      const StatisticalNode* parent,
                                      const StatisticalPacketHeader& header,
                                      const ClassTables& tables);
// The mean code that decodes nearest to `mean` under `parent` (null: the root
// in the header's box), and the reference length the node's position class is
// a ratio of (parent sigma_1, or the header's largest extent).
void encodeNodeMean(const double mean[3], const StatisticalNode* parent,
                    const StatisticalPacketHeader& header, std::uint16_t code[3]);
float positionClassReference(const StatisticalNode* parent, const StatisticalPacketHeader& header);
std::uint16_t encodeColor565(const double rgb[3]);

struct StatisticalPacketView {
  StatisticalPacketHeader header{};
  std::vector<StatisticalNode> nodes;  // the complete nodes of the bytes given
  // The nodes with children, in order: the decoder's state, so a longer
  // prefix of the same packet continues where this one ended.
  std::vector<std::uint32_t> withChildren;
};

// Decodes every complete node of a packet or packet prefix. Throws InputError
// naming `where` for a bad header, a class index outside the tables, or a
// breadth-first structure that does not hold (more children than nodes).
StatisticalPacketView decodeStatisticalPacket(std::span<const std::byte> bytes,
                                              const ClassTables& tables, const std::string& where);
StatisticalPacketView decodeStatisticalPacket(std::span<const Splat> records,
                                              const ClassTables& tables, const std::string& where);
// Decodes the complete nodes of `bytes` (a longer prefix of the packet `view`
// was decoded from, or any prefix when `view` is empty) that `view` lacks:
// what a render process does when more of a cached packet arrives. Throws as
// decodeStatisticalPacket, and InputError when the header changed.
void extendStatisticalPacket(StatisticalPacketView& view, std::span<const std::byte> bytes,
                             const ClassTables& tables, const std::string& where);

}  // namespace pointillist
