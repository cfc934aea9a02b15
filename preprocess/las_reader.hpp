#pragma once
// ASPRS LAS 1.0-1.4 reader, uncompressed; point data formats 0-10 (positions,
// and RGB where the format has it). LAZ is refused with a clear message.
#include <filesystem>

#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

PointCloud readLas(const std::filesystem::path& file, const ReadOptions& options);

}  // namespace pointillist::preprocess
