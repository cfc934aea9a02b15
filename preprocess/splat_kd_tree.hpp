#pragma once
// nanoflann's k-d tree over splat centres, for the preprocess's neighbour
// searches (normals and radii) and the statistical quality measure.
#include <cstddef>
#include <cstdint>
#include <nanoflann.hpp>
#include <span>

#include "common/splat.hpp"

namespace pointillist::preprocess {

struct SplatCloudAdaptor {
  std::span<const Splat> splats;
  std::size_t kdtree_get_point_count() const { return splats.size(); }
  float kdtree_get_pt(std::uint32_t index, std::size_t dim) const {
    return splats[index].position[dim];
  }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

using SplatKdTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, SplatCloudAdaptor>,
                                        SplatCloudAdaptor, 3, std::uint32_t>;

}  // namespace pointillist::preprocess
