#pragma once
// Triangle meshes (from OFF or PLY) turned into surface points, plus the small
// deterministic random generator shared with the scene generator.
#include <array>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "common/geometry.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

struct TriangleMesh {
  std::vector<Vec3d> vertices;
  std::vector<std::array<std::uint8_t, 4>> vertexColors;    // empty or one per vertex
  std::vector<std::array<float, 3>> vertexNormals;          // empty or one per vertex
  std::vector<std::array<std::uint32_t, 3>> triangles;      // indices already range-checked
  std::vector<std::array<std::uint8_t, 4>> triangleColors;  // empty or one per triangle
  std::uint64_t faces = 0;        // polygons in the file, before fan triangulation
  std::vector<bool> badVertices;  // empty, or true for NaN/Inf vertices (dropNonFinite)
};

// Samples exactly `count` points, area-weighted (jittered stratified over the
// cumulative area, so each triangle gets its expected share within one point).
// Normals are the triangle normals (winding order: counter-clockwise seen from
// the front); colours interpolate vertex colours, else use the triangle colour,
// else grey. Radii follow normals.hpp: r = sqrt(3 * area / (pi * count)), disks
// covering the surface about three times over. Zero-area triangles are skipped;
// a mesh with no triangle of positive area is an InputError naming `source`.
// The points are made on all cores from one random stream drawn in order, so
// they are the same on any number of cores.
PointCloud sampleMesh(const TriangleMesh& mesh, std::size_t count, std::uint64_t seed,
                      const std::string& source);

// Reads an OFF / COFF / NOFF / CNOFF file (ascii) as it is: polygons are fan-
// triangulated; NaN/Inf vertices are refused, or under dropNonFinite flagged in
// badVertices with the triangles using them left out.
TriangleMesh readOffMesh(const std::filesystem::path& file, const ReadOptions& options);

// readOffMesh, then sampled; a file without faces is a point cloud of its vertices.
PointCloud readOff(const std::filesystem::path& file, const ReadOptions& options);

// xoshiro256** seeded through splitmix64: the same numbers on every platform
// (std:: distributions are implementation-defined).
class Rng {
 public:
  explicit Rng(std::uint64_t seed);
  std::uint64_t next();
  // Uniform in [0, 1).
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Uniform integer in [0, n).
  std::uint64_t below(std::uint64_t n);

 private:
  std::uint64_t s_[4];
};

}  // namespace pointillist::preprocess
