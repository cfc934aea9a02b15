#pragma once
// Input side of pointillist-preprocess: reads any supported point cloud or
// mesh file, choosing the format reader (ply_reader, xyz_reader, las_reader,
// mesh_sampler's OFF reader) by extension. Their shared helpers are in
// reader_toolkit.hpp.
//
// Conventions shared by every reader:
//  - a splat whose normal is (0,0,0) has no normal; radius 0 means no radius;
//    estimateNormalsAndRadii() fills exactly those in (see normals.hpp);
//  - points without colour get mid grey (kDefaultGrey: 128,128,128,255) right away, so merged
//    clouds keep the colours of the files that had them;
//  - PointCloud::hasNormals / hasRadii are true only when every splat has one;
//    hasColors is true when the input carried colours;
//  - every InputError message starts with "<file>: line N: " (text) or
//    "<file>: byte N: " (binary) when the problem has a place.
#include <filesystem>
#include <functional>
#include <span>
#include <vector>

#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

// Dispatches on the extension (.ply .xyz .pts .txt .las .off, case-insensitive).
// Meshes (OFF, PLY with faces) are sampled to options.meshSamplePoints points.
PointCloud readPointCloud(const std::filesystem::path& file, const ReadOptions& options);

// Reads and concatenates several inputs. has* flags are AND-ed; per-splat
// missing attributes stay marked (zero normal / zero radius) for
// estimateNormalsAndRadii().
PointCloud readPointClouds(const std::vector<std::filesystem::path>& files,
                           const ReadOptions& options);

// Streams the points of `files`, in order, to `sink` in blocks of about
// options.sinkBlock, holding one block in memory (a mesh's samples whole;
// a LAS file with colours is read twice). Returns the merged flags and source, no splats; `count`
// gets the number of points. Progress is in bytes over all files.
PointCloud streamPointClouds(const std::vector<std::filesystem::path>& files,
                             const ReadOptions& options,
                             const std::function<void(std::span<const Splat>)>& sink,
                             std::uint64_t& count);

}  // namespace pointillist::preprocess
