#pragma once
// Built-in procedural scenes, so that Pointillist runs with no download.
//
// "city" (the default demo) on a 400 m x 400 m square around the origin, z up:
//  - terrain: a flat town square (roads, pavements, lawns, a paved plaza)
//    rising into hills with a height-coloured surface (grass, earth, rock,
//    snow); point density falls off with distance from the centre;
//  - a domed building (drum, hemispherical dome with ribs, lantern and ball)
//    inside a ring of 16 columns carrying a torus-shaped ring beam;
//    four half-torus gate arches on the main roads;
//  - repeated objects: two house types on the street grid and two tree types
//    along the town edge and on the hills. Every copy is an exact translated
//    copy of one local point set: local coordinates and translations are
//    multiples of 2^-12 and small enough that float addition is exact, so
//    copy - original == translation bit for bit (for the instancing stage).
// "sphere" (unit sphere) and "torus" are small test shapes.
//
// Surfaces are sampled on jittered grids of area-preserving parameterisations
// (evenly spread points, no clumps or holes); ground under buildings is left
// out. All splats carry exact normals, colours and radii (disks of three times
// the area per point, the same rule as normals.hpp). The point count is exactly
// targetPoints; the result depends only on (name, targetPoints, seed).
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

std::vector<std::string> generatorNames();

// Throws UsageError for an unknown name or targetPoints == 0.
PointCloud generateScene(const std::string& name, std::size_t targetPoints, std::uint64_t seed);

}  // namespace pointillist::preprocess
