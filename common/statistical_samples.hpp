#pragma once
// The samples statistical points are generated from (seed 004 §6.1, §8.2): a
// fixed sequence of standard-normal vectors, the same every frame and in every
// process, so generated points never flicker and a tile equals the same pixels
// of a whole frame. Sample i of a node is drawn with GaussianSample i.
#include <cstdint>
#include <random>
#include <vector>

#include "common/splat.hpp"
#include "common/statistical_node.hpp"

namespace pointillist {

// 32 bytes: one vertex of the render's static sample buffer.
struct GaussianSample {
  float position[3];  // 3D standard normal
  float normal[2];    // 2D standard normal (tangent plane of the normals)
  float color[3];     // 3D standard normal
};
static_assert(sizeof(GaussianSample) == 32);

enum class SampleSequence {
  Sobol,   // quasi-random: Boost.Random's Sobol sequence (8 dimensions)
  Pseudo,  // pseudo-random (std::mt19937_64 from the seed), for comparison
};

// The first `count` samples: each 8-dimensional point u in (0,1)^8 of the
// sequence (the Sobol sequence's first point, the origin, skipped) mapped per
// coordinate through the inverse normal CDF; a point is skipped when its
// position, normal or colour part is longer than kStatisticalGamma, so every
// generated point lies inside its node's gamma ellipsoid.
std::vector<GaussianSample> gaussianSamples(std::uint32_t count,
                                            SampleSequence sequence = SampleSequence::Sobol,
                                            std::uint64_t seed = 1);

// The point `sample` generates from `node` (formulas at StatisticalNode), in
// float as the vertex shader computes it; alpha 255, radius as given.
Splat generatePoint(const StatisticalNode& node, const GaussianSample& sample, float radius);

// A random right-handed orthonormal frame (rows): random nodes for tests and
// pointillist-statistical-table --speed.
void randomFrame(std::mt19937& rng, float (&axes)[3][3]);

}  // namespace pointillist
