#pragma once
// smallestEigen3 (common/geometry.hpp) of many matrices at once, in SIMD
// (Highway, run-time dispatch): the normals of a scan and the level-splats
// each take one per point or splat, and one at a time is a chain of divisions
// and square roots that leaves the core waiting. The same bits as the scalar
// function for every matrix: the same operations in its order, no fused
// multiply-add, and the matrices it hands to Jacobi go to it too.
#include <span>

#include "common/geometry.hpp"

namespace pointillist::preprocess {

// out[i] = smallestEigen3(matrices[i]); out needs matrices.size() entries.
void smallestEigen3Batch(std::span<const Sym3> matrices, std::span<SmallestEigen3> out);

}  // namespace pointillist::preprocess
