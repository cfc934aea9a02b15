#pragma once
// The refinement step of the level-splats (seed 003 §4.1.2, after Pauly et
// al.): each input goes to the cluster Gaussian under which it is most
// likely, i.e. with the lowest (x - mean)^T inverse (x - mean) + log det.
// Every cluster of a cell is tried, in SIMD (Highway, run-time dispatch) over
// inputs: cheaper than choosing a few near clusters first. The costs are the
// scalar expression's bits (explicit multiplies and adds in its order, no fused
// multiply-add), so every target picks the same clusters.
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace pointillist::preprocess {

// A cluster's Gaussian as the search reads it.
struct GaussianRecord {
  double mean[3];
  double inverse[6];  // upper triangle: xx, xy, xz, yy, yz, zz
  double logDet;
};

// cost = ((i0 dx dx + i3 dy dy) + i5 dz dz) + 2 ((i1 dx dy + i2 dx dz) + i4 dy dz)
//        + logDet, with d = x - mean; each product taken left to right.
double gaussianCost(const GaussianRecord& g, double x, double y, double z);

// For each input position: assignment[i] becomes the cluster of lowest cost,
// the lowest index among equal costs; an input no cost below +infinity
// reaches (NaN) keeps its cluster. Returns whether any changed. Throws
// std::invalid_argument unless there is one assignment per position.
bool assignLikeliestGaussians(std::span<const std::array<double, 3>> positions,
                              std::span<const GaussianRecord> gaussians,
                              std::span<std::uint32_t> assignment);

}  // namespace pointillist::preprocess
