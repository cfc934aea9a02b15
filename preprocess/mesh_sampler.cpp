#include "preprocess/mesh_sampler.hpp"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/reader_toolkit.hpp"

namespace pointillist::preprocess {

namespace {

std::uint64_t splitMix(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

std::uint64_t rotl(std::uint64_t x, int k) {
  return (x << k) | (x >> (64 - k));
}

}  // namespace

Rng::Rng(std::uint64_t seed) {
  std::uint64_t state = seed;
  for (auto& s : s_) s = splitMix(state);
}

std::uint64_t Rng::next() {
  const std::uint64_t result = rotl(s_[1] * 5, 7) * 9;
  const std::uint64_t t = s_[1] << 17;
  s_[2] ^= s_[0];
  s_[3] ^= s_[1];
  s_[1] ^= s_[2];
  s_[0] ^= s_[3];
  s_[2] ^= t;
  s_[3] = rotl(s_[3], 45);
  return result;
}

std::uint64_t Rng::below(std::uint64_t n) {
  // Rejection removes the modulo bias.
  const std::uint64_t limit =
      std::numeric_limits<std::uint64_t>::max() - std::numeric_limits<std::uint64_t>::max() % n;
  for (;;) {
    const std::uint64_t x = next();
    if (x < limit) return x % n;
  }
}

PointCloud sampleMesh(const TriangleMesh& mesh, std::size_t count, std::uint64_t seed,
                      const std::string& source) {
  if (count == 0) throw UsageError(source + ": the mesh sample count must be positive");
  if (mesh.triangles.empty()) throw InputError(source + ": mesh has no faces");

  // Zero area is judged relative to the mesh size so that scale does not matter.
  const double inf = std::numeric_limits<double>::infinity();
  Vec3d lo{inf, inf, inf}, hi{-inf, -inf, -inf};
  for (const Vec3d& v : mesh.vertices) {
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) continue;
    for (std::size_t k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], v[k]);
      hi[k] = std::max(hi[k], v[k]);
    }
  }
  const double diagonal = length(sub(hi, lo));
  const double minArea = 1e-14 * diagonal * diagonal;

  std::vector<std::uint32_t> used;  // triangles with positive area
  std::vector<double> cumulative;   // inclusive prefix sums of their areas
  used.reserve(mesh.triangles.size());
  cumulative.reserve(mesh.triangles.size());
  double total = 0.0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Vec3d& a = mesh.vertices[tri[0]];
    const double area =
        0.5 * length(cross(sub(mesh.vertices[tri[1]], a), sub(mesh.vertices[tri[2]], a)));
    if (!(area > minArea)) continue;
    total += area;
    used.push_back(static_cast<std::uint32_t>(t));
    cumulative.push_back(total);
  }
  if (used.empty()) {
    throw InputError(source + ": mesh has no triangle with non-zero area (all " +
                     std::to_string(mesh.triangles.size()) + " are degenerate)");
  }

  PointCloud cloud;
  cloud.source = source;
  cloud.hasNormals = true;
  cloud.hasRadii = true;
  const bool vertexColors = mesh.vertexColors.size() == mesh.vertices.size();
  const bool triangleColors = mesh.triangleColors.size() == mesh.triangles.size();
  cloud.hasColors = vertexColors || triangleColors;
  // Pages mapped on all threads first: the resize would fault them on one.
  resizePopulated(cloud.splats, count, 0);
  const auto radius =
      static_cast<float>(std::sqrt(3.0 * total / (std::numbers::pi * static_cast<double>(count))));

  // Point i from its three random numbers (where along the area, then the
  // two barycentric draws) and the triangle its area falls in.
  const auto samplePoint = [&](std::size_t i, std::uint32_t t, const double* draw) {
    const auto& tri = mesh.triangles[t];
    const Vec3d& a = mesh.vertices[tri[0]];
    const Vec3d& b = mesh.vertices[tri[1]];
    const Vec3d& c = mesh.vertices[tri[2]];
    const double r1 = std::sqrt(draw[1]);
    const double r2 = draw[2];
    const double wa = 1.0 - r1, wb = r1 * (1.0 - r2), wc = r1 * r2;
    const Vec3d p = add(add(scale(a, wa), scale(b, wb)), scale(c, wc));
    const Vec3d n = cross(sub(b, a), sub(c, a));
    const double len = length(n);

    Splat& s = cloud.splats[i];
    for (std::size_t k = 0; k < 3; ++k) {
      s.position[k] = static_cast<float>(p[k]);
      // Divided, not normalized(): its reciprocal would change last bits.
      s.normal[k] = static_cast<float>(n[k] / len);
    }
    s.radius = radius;
    if (vertexColors) {
      for (std::size_t k = 0; k < 4; ++k) {
        const double value = wa * mesh.vertexColors[tri[0]][k] + wb * mesh.vertexColors[tri[1]][k] +
                             wc * mesh.vertexColors[tri[2]][k];
        s.color[k] = detail::colorFromByte(value);
      }
    } else if (triangleColors) {
      std::copy(mesh.triangleColors[t].begin(), mesh.triangleColors[t].end(), s.color);
    } else {
      s.color[0] = s.color[1] = s.color[2] = kDefaultGrey;
      s.color[3] = 255;
    }
  };

  // One random stream, three numbers a point in order: drawn on this thread
  // a chunk at a time, the points made from them on all threads. A block of
  // points finds its first triangle by a binary search, where the one-thread
  // walk over the cumulative areas arrived: the same points, bit for bit, on
  // any number of threads.
  Rng rng(seed);
  const double step = total / static_cast<double>(count);
  constexpr std::size_t kChunk = std::size_t{1} << 18;
  constexpr std::size_t kBlock = std::size_t{1} << 14;
  std::vector<double> draws(3 * std::min(count, kChunk));
  for (std::size_t first = 0; first < count; first += kChunk) {
    const std::size_t n = std::min(kChunk, count - first);
    for (std::size_t j = 0; j < 3 * n; ++j) draws[j] = rng.uniform();
    // Jittered stratification: sample i lands in [i, i+1) * step of the area.
    const auto target = [&](std::size_t j) {
      return (static_cast<double>(first + j) + draws[3 * j]) * step;
    };
    const auto sampleBlock = [&](std::size_t block) {
      const std::size_t begin = block * kBlock, end = std::min(n, begin + kBlock);
      // The first triangle whose cumulative area passes the target (the last
      // at most): where the walk below stands for that target.
      auto u = static_cast<std::size_t>(
          std::upper_bound(cumulative.begin(), cumulative.end(), target(begin)) -
          cumulative.begin());
      u = std::min(u, used.size() - 1);
      for (std::size_t j = begin; j < end; ++j) {
        const double at = target(j);
        while (u + 1 < used.size() && cumulative[u] <= at) ++u;
        samplePoint(first + j, used[u], draws.data() + 3 * j);
      }
    };
    parallelFor((n + kBlock - 1) / kBlock, 0, sampleBlock, 1);
  }
  return cloud;
}

namespace {

using detail::failAtLine;

// Colour from 3 or 4 OFF fields: integers are 0..255, decimals 0..1.
bool offColor(const std::vector<std::string_view>& fields, std::size_t at,
              std::array<std::uint8_t, 4>& color) {
  const std::size_t n = fields.size() - std::min(at, fields.size());
  if (n != 3 && n != 4) return false;
  color = {0, 0, 0, 255};
  for (std::size_t k = 0; k < n; ++k) {
    double v = 0.0;
    if (!detail::parseDouble(fields[at + k], v)) return false;
    const bool decimal = fields[at + k].find_first_of(".eE") != std::string_view::npos;
    color[k] = decimal ? detail::colorFromUnit(v) : detail::colorFromByte(v);
  }
  return true;
}

}  // namespace

TriangleMesh readOffMesh(const std::filesystem::path& file, const ReadOptions& options) {
  detail::FileReader reader(file);
  detail::CloudBuilder progress(file, options);  // only for its throttled progress
  std::vector<std::string_view> f;

  // Next non-blank, comment-stripped line into `f`; false at end of file.
  const auto next = [&]() {
    std::string_view line;
    for (;;) {
      if (!reader.readLine(line)) return false;
      const std::size_t hash = line.find('#');
      if (hash != std::string_view::npos) line = line.substr(0, hash);
      detail::splitFields(line, f);
      if (!f.empty()) return true;
    }
  };

  if (!next()) detail::failFile(file, "empty file");
  const std::string_view keyword = f[0];
  bool withColor = false;
  bool withNormal = false;
  bool withTexture = false;
  {
    std::string_view k = keyword;
    if (k.starts_with("ST")) {
      withTexture = true;
      k.remove_prefix(2);
    }
    if (k.starts_with("C")) {
      withColor = true;
      k.remove_prefix(1);
    }
    if (k.starts_with("N")) {
      withNormal = true;
      k.remove_prefix(1);
    }
    if (k != "OFF") {
      failAtLine(file, reader.lineNumber(),
                 "not an OFF file (expected OFF, COFF, NOFF or CNOFF, got '" +
                     std::string(keyword) + "')");
    }
  }
  std::size_t countsAt = 1;  // the counts may follow the keyword on the same line
  if (f.size() == 1) {
    if (!next()) failAtLine(file, reader.lineNumber(), "truncated header: no vertex/face counts");
    countsAt = 0;
  } else if (f[1] == "BINARY") {
    failAtLine(file, reader.lineNumber(), "binary OFF is not supported");
  }
  std::uint64_t vertexCount = 0;
  std::uint64_t faceCount = 0;
  if (f.size() < countsAt + 2 || !detail::parseUnsigned(f[countsAt], vertexCount) ||
      !detail::parseUnsigned(f[countsAt + 1], faceCount)) {
    failAtLine(file, reader.lineNumber(), "expected '<vertices> <faces> <edges>' counts");
  }
  // Each vertex line needs at least "0 0 0\n", each face "3 0 1 2\n".
  if (vertexCount > reader.size() / 6 || faceCount > reader.size() / 8) {
    failAtLine(file, reader.lineNumber(),
               "absurd counts (" + std::to_string(vertexCount) + " vertices, " +
                   std::to_string(faceCount) + " faces) for a file of " +
                   std::to_string(reader.size()) + " bytes");
  }
  if (vertexCount == 0) detail::failFile(file, "contains no vertices");
  const std::size_t colorAt = withNormal ? 6 : 3;
  const std::size_t minFields = colorAt + (withColor ? 3 : 0) + (withTexture ? 2 : 0);

  TriangleMesh mesh;
  mesh.faces = faceCount;
  mesh.vertices.reserve(static_cast<std::size_t>(vertexCount));
  if (withColor) mesh.vertexColors.reserve(static_cast<std::size_t>(vertexCount));
  if (withNormal) mesh.vertexNormals.reserve(static_cast<std::size_t>(vertexCount));
  std::uint64_t badVertices = 0;
  for (std::uint64_t i = 0; i < vertexCount; ++i) {
    if (!next()) {
      failAtLine(file, reader.lineNumber(),
                 "truncated vertex list (expected " + std::to_string(vertexCount) +
                     " vertices, got " + std::to_string(i) + ")");
    }
    const std::uint64_t at = reader.lineNumber();
    if (f.size() < minFields) {
      failAtLine(file, at,
                 "vertex " + std::to_string(i) + " has " + std::to_string(f.size()) +
                     " values, expected " + std::to_string(minFields));
    }
    double v[6] = {};
    const std::size_t numbers = withNormal ? 6 : 3;
    for (std::size_t k = 0; k < numbers; ++k) {
      if (!detail::parseDouble(f[k], v[k])) {
        failAtLine(file, at, "not a number: '" + std::string(f[k]) + "'");
      }
    }
    if (withColor) {
      // Colours take 3 or 4 fields, before optional texture coordinates.
      f.resize(f.size() - (withTexture ? 2 : 0));
      std::array<std::uint8_t, 4> color{};
      if (!offColor(f, colorAt, color)) failAtLine(file, at, "malformed vertex colour");
      mesh.vertexColors.push_back(color);
    }
    bool finite = true;
    for (std::size_t k = 0; k < numbers; ++k) finite = finite && detail::fitsFloat(v[k]);
    if (!finite) {
      if (!options.dropNonFinite) {
        failAtLine(file, at,
                   "non-finite value (NaN, Inf or beyond float range) in vertex " +
                       std::to_string(i) + " (pass --drop-non-finite to drop such points)");
      }
      mesh.badVertices.resize(static_cast<std::size_t>(vertexCount), false);
      mesh.badVertices[static_cast<std::size_t>(i)] = true;
      ++badVertices;
    }
    mesh.vertices.push_back({v[0], v[1], v[2]});
    if (withNormal) {
      mesh.vertexNormals.push_back(
          {static_cast<float>(v[3]), static_cast<float>(v[4]), static_cast<float>(v[5])});
    }
    if ((i & 4095) == 0) progress.progress(reader.offset(), reader.size());
  }

  mesh.triangles.reserve(static_cast<std::size_t>(faceCount));
  bool faceColors = faceCount > 0;
  std::vector<std::array<std::uint8_t, 4>> colors;
  for (std::uint64_t i = 0; i < faceCount; ++i) {
    if (!next()) {
      failAtLine(file, reader.lineNumber(),
                 "truncated face list (expected " + std::to_string(faceCount) + " faces, got " +
                     std::to_string(i) + ")");
    }
    const std::uint64_t at = reader.lineNumber();
    std::uint64_t n = 0;
    if (!detail::parseUnsigned(f[0], n)) {
      failAtLine(file, at, "expected a face vertex count, got '" + std::string(f[0]) + "'");
    }
    // Compared without arithmetic on n: a count near 2^64 must not wrap.
    if (n > f.size() - 1) {
      failAtLine(file, at,
                 "face " + std::to_string(i) + " lists " + std::to_string(f.size() - 1) +
                     " indices, expected " + std::to_string(n));
    }
    std::array<std::uint8_t, 4> color{};
    faceColors = faceColors && offColor(f, n + 1, color);
    std::uint32_t first = 0;
    std::uint32_t previous = 0;
    for (std::uint64_t k = 0; k < n; ++k) {
      std::uint64_t index = 0;
      if (!detail::parseUnsigned(f[k + 1], index) || index >= vertexCount) {
        failAtLine(file, at,
                   "face vertex index " + std::string(f[k + 1]) + " out of range (the mesh has " +
                       std::to_string(vertexCount) + " vertices)");
      }
      const auto current = static_cast<std::uint32_t>(index);
      if (k == 0) first = current;
      // Fan triangulation; faces with fewer than 3 corners add nothing.
      if (k >= 2) {
        const bool bad =
            badVertices > 0 &&
            (mesh.badVertices[first] || mesh.badVertices[previous] || mesh.badVertices[current]);
        if (!bad) {
          mesh.triangles.push_back({first, previous, current});
          colors.push_back(color);
        }
      }
      previous = current;
    }
    if ((i & 4095) == 0) progress.progress(reader.offset(), reader.size());
  }
  if (faceColors) mesh.triangleColors = std::move(colors);
  progress.progress(reader.size(), reader.size());
  return mesh;
}

PointCloud readOff(const std::filesystem::path& file, const ReadOptions& options) {
  const TriangleMesh mesh = readOffMesh(file, options);
  const std::size_t bad =
      static_cast<std::size_t>(std::count(mesh.badVertices.begin(), mesh.badVertices.end(), true));
  if (bad > 0) {
    std::cerr << "warning: " << file.string() << ": dropped " << bad
              << " vertices with NaN/Inf values"
              << (mesh.faces > 0 ? " and the faces using them" : "") << "\n";
  }
  if (mesh.faces > 0) {
    if (mesh.triangles.empty()) detail::failFile(file, "mesh has no usable faces");
    return sampleMesh(mesh, options.meshSamplePoints, options.seed, file.string());
  }
  // No faces: the vertices are the points (NaN/Inf ones were refused or flagged).
  detail::CloudBuilder builder(file, options);
  builder.reserve(mesh.vertices.size(), mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!mesh.badVertices.empty() && mesh.badVertices[i]) continue;
    Splat s = detail::greySplat();
    for (std::size_t k = 0; k < 3; ++k) {
      s.position[k] = static_cast<float>(mesh.vertices[i][k]);
      if (!mesh.vertexNormals.empty()) s.normal[k] = mesh.vertexNormals[i][k];
    }
    if (!mesh.vertexColors.empty()) {
      std::copy(mesh.vertexColors[i].begin(), mesh.vertexColors[i].end(), s.color);
    }
    builder.add(s, 0, 0);
  }
  return builder.finish(!mesh.vertexNormals.empty(), !mesh.vertexColors.empty(), false);
}

}  // namespace pointillist::preprocess
