#pragma once
// What the walk tests for every cell, taken out of the 64-byte cells once per
// dataset and size scale: bounds grown by the largest splat radius, the
// bounding sphere, the normal cone decoded from its quantized form, and the
// links and flags the walk follows. One 64-byte record per cell is all the
// walk reads until it draws a cell (the octree cell is read then): with the
// cell and a double-precision cone beside it, a visited cell cost two and a
// half cache lines.
#include <cstdint>
#include <span>
#include <vector>

#include <glm/glm.hpp>

#include "common/octree_cell.hpp"

namespace pointillist::traverse {

struct alignas(64) CellCulling {
  glm::vec3 low{};  // bounds grown by maxSplatRadius * sizeScale
  glm::vec3 high{};
  glm::vec3 coneAxis{};   // unit
  float cosCone = -1.0f;  // half-angle cosine in (0, 1]; -1: no cone to cull by
  float sinCone = 0.0f;
  float radius = 0.0f;          // of the sphere around the grown bounds' centre
  float maxSplatRadius = 0.0f;  // the cell's, not scaled
  std::uint32_t nextSibling = kNoIndex;
  std::uint32_t topLevel = kNoIndex;
  std::uint32_t flags = 0;  // the bits below; the cell's level in bits 8-15

  static constexpr std::uint32_t kLeaf = 1, kHasPoints = 2, kHasSplats = 4, kWithinParent = 8,
                                 kChildrenInOneRange = 16;
  static constexpr unsigned kLevelShift = 8;
  bool isLeaf() const { return (flags & kLeaf) != 0; }
  std::uint8_t level() const { return static_cast<std::uint8_t>(flags >> kLevelShift); }
  bool hasPoints() const { return (flags & kHasPoints) != 0; }
  bool hasSplats() const { return (flags & kHasSplats) != 0; }
  glm::vec3 centre() const { return 0.5f * (low + high); }
};
static_assert(sizeof(CellCulling) == 64);

// The level-splats of all of a cell's children, where they are one run of
// the packet: every child has level-splats, lies within the cell, and the
// children are of one level (their splats then follow each other in the
// layer, children in depth-first order). The walk takes them at once when it
// knows every child would be drawn from its level-splats
// (CellCulling::kChildrenInOneRange).
struct ChildrenSplats {
  std::uint32_t offset = 0;
  std::uint32_t count = 0;
  float maxSplatRadius = 0.0f;  // the largest of the children's
  std::uint8_t level = 0;       // the children's
};

CellCulling cellCulling(const OctreeCell& cell, float sizeScale);

class CullingTable {
 public:
  CullingTable(std::span<const OctreeCell> cells, float sizeScale);

  std::span<const OctreeCell> cells() const { return cells_; }
  float sizeScale() const { return sizeScale_; }
  const CellCulling& operator[](std::uint32_t index) const { return culling_[index]; }
  // The cell's grown bounds lie within its parent's: a plane the parent's lie
  // wholly inside holds the cell's too.
  bool withinParent(std::uint32_t index) const {
    return (culling_[index].flags & CellCulling::kWithinParent) != 0;
  }
  // Valid where the cell's flags have kChildrenInOneRange.
  const ChildrenSplats& childrenSplats(std::uint32_t index) const { return children_[index]; }

 private:
  std::span<const OctreeCell> cells_;
  float sizeScale_;
  std::vector<CellCulling> culling_;
  std::vector<ChildrenSplats> children_;
};

// True when every splat of the cell faces away from the eye (conservative:
// combines the normal cone with the cone of view directions onto the cell).
bool cellBackfacing(const CellCulling& cell, const glm::vec3& eye);

enum class Facing {
  Away,    // every splat of the subtree faces away (cellBackfacing)
  Toward,  // every splat faces the eye: no cell below can face away
  Mixed,
};
// cellBackfacing and its mirror test in one: the same bound with the cone's
// axis reversed.
Facing cellFacing(const CellCulling& cell, const glm::vec3& eye);

// Euclidean distance from the eye to the grown bounds (0 inside).
float distanceToCell(const CellCulling& cell, const glm::vec3& eye);

}  // namespace pointillist::traverse
