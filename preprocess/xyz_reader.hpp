#pragma once
// XYZ / PTS / TXT text point reader.
//
// The column count decides the layout, once per file, and every data line must
// have the same count:
//   3: x y z                    4: x y z intensity (intensity ignored)
//   6: x y z nx ny nz  or  x y z r g b (told apart on the first lines: unit
//      vectors are normals, otherwise values in 0..255 are colours)
//   7: x y z intensity r g b (Leica PTS)
//   9: x y z nx ny nz r g b  or  x y z r g b nx ny nz (same test)
// A first data line holding a single integer is a PTS point count and must
// match the data. '#' starts a comment; commas count as blanks.
#include <filesystem>

#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

PointCloud readXyz(const std::filesystem::path& file, const ReadOptions& options);

}  // namespace pointillist::preprocess
