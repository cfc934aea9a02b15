#pragma once
// PLY reader (ascii, binary little/big endian); PLY files with faces are meshes
// and get sampled.
#include <filesystem>

#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

PointCloud readPly(const std::filesystem::path& file, const ReadOptions& options);

}  // namespace pointillist::preprocess
