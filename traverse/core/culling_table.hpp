#pragma once
// What the walk tests for every cell, taken out of the 64-byte cells once per
// dataset and size scale: bounds grown by the largest splat radius, the
// bounding sphere, and the normal cone decoded from its quantized form.
// Decoding the cone (a normalisation in double) for every visited cell was
// a third of the walk's time; the decisions are the same, bit for bit.
#include <cstdint>
#include <span>
#include <vector>

#include <glm/glm.hpp>

#include "common/octree_cell.hpp"

namespace pointillist::traverse {

struct CellCulling {
  glm::vec3 low{};  // bounds grown by maxSplatRadius * sizeScale
  glm::vec3 high{};
  glm::vec3 centre{};  // of the grown bounds
  float radius = 0.0f;
  glm::dvec3 coneAxis{};  // unit
  double cosCone = -1.0;  // half-angle cosine in (0, 1]; -1: no cone to cull by
  double sinCone = 0.0;
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
  bool withinParent(std::uint32_t index) const { return withinParent_[index] != 0; }

 private:
  std::span<const OctreeCell> cells_;
  float sizeScale_;
  std::vector<CellCulling> culling_;
  std::vector<std::uint8_t> withinParent_;
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
