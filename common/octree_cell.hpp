#pragma once
// The 64-byte octree cell of seed 003 §4.1.1, stored depth-first in the
// octree-cell-array. Traverse processes load only an array of these.
#include <cstdint>
#include <limits>
#include <type_traits>

namespace pointillist {

inline constexpr std::uint32_t kNoIndex = std::numeric_limits<std::uint32_t>::max();

struct OctreeCell {
  // Tight bounds of the centres of every splat in the subtree (points and
  // level-splats); expand by maxSplatRadius for conservative culling.
  float boundsMin[3];
  float boundsMax[3];
  // Normal cone: mean normal (snorm16) and cosine of the half angle (snorm16),
  // quantized conservatively (the stored cone contains the true one) and
  // covering every normal in the subtree, points and level-splats.
  // coneCos == -32767 means "no cone" (never back-face cull); it is also
  // stored when any normal in the subtree is unknown. Decode with
  // decodeNormalCone() in common/geometry.hpp (the axis is renormalized).
  std::int16_t coneAxis[3];
  std::int16_t coneCos;
  // Depth-first index of the next sibling, or of the nearest ancestor's next
  // sibling; kNoIndex when the walk ends after this subtree.
  std::uint32_t nextSibling;
  // Index into the top-level table; kNoIndex above the top-level depth.
  std::uint32_t topLevel;
  // All original points of this subtree, in splats, relative to the first
  // splat of its top-level cell (seed 003 fig. 3: "added start index").
  std::uint32_t pointsOffset;
  std::uint32_t pointsCount;
  // This cell's own level-splats, same relative addressing (they precede the
  // packet's points, so splatsOffset + splatsCount <= the packet's
  // levelSplatCount). Cells above the top-level depth have all four fields zero.
  std::uint32_t splatsOffset;
  std::uint32_t splatsCount;
  // Largest radius of any splat in the subtree (points and level-splats);
  // never larger than the parent's. Used for conservative culling and for the
  // level of detail rule documented in common/dataset.hpp.
  float maxSplatRadius;
  // Seed 003 §4.1.2: points 0, leaves 1, others 1 + max(children).
  std::uint8_t level;
  std::uint8_t depth;
  std::uint8_t childCount;
  std::uint8_t flags;  // bit 0: leaf

  bool isLeaf() const { return (flags & 1u) != 0; }
};

inline constexpr std::uint8_t kCellFlagLeaf = 1;

static_assert(sizeof(OctreeCell) == 64, "seed 003: octree cells are aligned in 64 bytes");
static_assert(std::is_trivially_copyable_v<OctreeCell>);

}  // namespace pointillist

namespace pointillist {

// One entry of the top-level table: where a top-level cell's data packet lives
// in the point-array file. The packet is layered coarse-first: the level-splats
// of the cell itself and every cell beneath it come first (levelSplatCount
// splats, by level from the highest down, cells of one level in depth-first
// order), then the cell's original points (pointCount splats, depth-first leaf
// order). A prefix of the packet is therefore a level of detail: the traversal
// of a distant cell draws from its first layers only, and only those travel.
// A dataset built with --instanced may hold, between the level-splats and the
// points, the cell's points as vertex and transformation streams
// (instancedRecordCount 32-byte records, common/instanced_section.hpp): the
// instanced mode draws full detail from that shorter prefix.
// Its checksum (common/checksum.hpp) is in the dataset (Dataset::packetChecksum).
struct TopLevelCell {
  std::uint32_t cellIndex;  // index in the octree-cell-array
  std::uint32_t pointCount;
  std::uint32_t levelSplatCount;
  std::uint32_t instancedRecordCount;  // 0: none
  std::uint64_t byteOffset;            // in the point-array file
  std::uint64_t byteSize;              // (pointCount + levelSplatCount + instancedRecordCount) * 32
};

static_assert(sizeof(TopLevelCell) == 32);

// Records of a packet: level-splats, instanced section, points.
inline std::uint64_t packetRecords(const TopLevelCell& t) {
  return std::uint64_t{t.levelSplatCount} + t.instancedRecordCount + t.pointCount;
}
// Where the packet's original points start.
inline std::uint64_t pointsStart(const TopLevelCell& t) {
  return std::uint64_t{t.levelSplatCount} + t.instancedRecordCount;
}
// A drawn range starting at `offset` is the instanced section (no range of
// level-splats or points starts inside it).
inline bool inInstancedSection(const TopLevelCell& t, std::uint64_t offset) {
  return offset >= t.levelSplatCount && offset < pointsStart(t);
}
static_assert(std::is_trivially_copyable_v<TopLevelCell>);

}  // namespace pointillist
