// Readers: every PLY / XYZ / LAS / OFF variant written here round-trips; real
// libcgal-demo scans give the counts and values read by hand from the files;
// every bad input gives an InputError naming the file and the place.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/mesh_sampler.hpp"
#include "preprocess/reader_toolkit.hpp"
#include "preprocess/readers.hpp"

namespace fs = std::filesystem;
using pointillist::InputError;
using pointillist::Splat;
using pointillist::UsageError;
using namespace pointillist::preprocess;

namespace {

fs::path dataDir() {
  return fs::path(POINTILLIST_TEST_DATA_DIR) / "data";
}

#define REQUIRE_TEST_DATA()                                        \
  if (!fs::exists(dataDir())) {                                    \
    GTEST_SKIP() << "test data missing at " << dataDir()           \
                 << "; run `bash deploy/fetch-test-data.sh` once"; \
  }

class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = fs::temp_directory_path() /
            ("pointillist-readers-" + std::to_string(::getpid()) + "-" + info->name());
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  fs::path write(const std::string& name, const std::string& bytes) const {
    const fs::path file = path_ / name;
    std::ofstream out(file, std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    return file;
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// Runs `f`, expects an InputError whose message contains every `needles` entry.
void expectInputError(const std::function<void()>& f, const std::vector<std::string>& needles) {
  try {
    f();
    ADD_FAILURE() << "no InputError thrown (expected one mentioning '" << needles.front() << "')";
  } catch (const InputError& e) {
    const std::string what = e.what();
    for (const std::string& needle : needles) {
      EXPECT_NE(what.find(needle), std::string::npos)
          << "message '" << what << "' lacks '" << needle << "'";
    }
  }
}

ReadOptions defaults() {
  ReadOptions options;
  options.meshSamplePoints = 2000;
  return options;
}

// Reference points whose coordinates print exactly in decimal (multiples of 1/8).
std::vector<Splat> referencePoints(std::size_t n) {
  std::vector<Splat> points(n);
  for (std::size_t i = 0; i < n; ++i) {
    Splat& s = points[i];
    const auto f = static_cast<float>(i);
    s.position[0] = f * 0.125f - 3.0f;
    s.position[1] = 100.5f - f * 0.25f;
    s.position[2] = (i % 7 == 0) ? -1234.375f : f * 2.5f;
    const double a = 0.37 * static_cast<double>(i), b = 0.11 * static_cast<double>(i) + 0.2;
    s.normal[0] = static_cast<float>(std::cos(a) * std::sin(b));
    s.normal[1] = static_cast<float>(std::sin(a) * std::sin(b));
    s.normal[2] = static_cast<float>(std::cos(b));
    s.radius = 0.5f + f * 0.25f;
    s.color[0] = static_cast<std::uint8_t>(i * 37 % 256);
    s.color[1] = static_cast<std::uint8_t>(255 - i * 11 % 256);
    s.color[2] = static_cast<std::uint8_t>(i * 5 % 256);
    s.color[3] = static_cast<std::uint8_t>(200 + i % 50);
  }
  return points;
}

// --------------------------------------------------------------- PLY writer

struct PlyProperty {
  std::string type;  // "float", "uchar", ... or "list uchar int"
  std::string name;
};

enum class PlyFormat { Ascii, Little, Big };

template <class T>
void putBinary(std::string& out, T value, bool big) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if (big != (std::endian::native == std::endian::big)) std::reverse(bytes, bytes + sizeof(T));
  out.append(bytes, sizeof(T));
}

void putValue(std::string& out, const std::string& type, double value, PlyFormat format) {
  if (format == PlyFormat::Ascii) {
    std::ostringstream s;
    s.precision(17);
    if (type == "float" || type == "float32" || type == "double" || type == "float64") {
      s << value;
    } else {
      s << static_cast<long long>(value);
    }
    out += s.str();
    out += ' ';
    return;
  }
  const bool big = format == PlyFormat::Big;
  if (type == "char" || type == "int8") return putBinary(out, static_cast<std::int8_t>(value), big);
  if (type == "uchar" || type == "uint8")
    return putBinary(out, static_cast<std::uint8_t>(value), big);
  if (type == "short" || type == "int16")
    return putBinary(out, static_cast<std::int16_t>(value), big);
  if (type == "ushort" || type == "uint16")
    return putBinary(out, static_cast<std::uint16_t>(value), big);
  if (type == "int" || type == "int32")
    return putBinary(out, static_cast<std::int32_t>(value), big);
  if (type == "uint" || type == "uint32")
    return putBinary(out, static_cast<std::uint32_t>(value), big);
  if (type == "float" || type == "float32") return putBinary(out, static_cast<float>(value), big);
  if (type == "double" || type == "float64") return putBinary(out, value, big);
  ADD_FAILURE() << "bad type " << type;
}

bool isFloatType(const std::string& t) {
  return t == "float" || t == "float32" || t == "double" || t == "float64";
}

// Value of a named vertex property for a reference point.
double vertexValue(const Splat& s, const PlyProperty& p, std::size_t i) {
  const std::string& n = p.name;
  if (n == "x") return static_cast<double>(s.position[0]);
  if (n == "y") return static_cast<double>(s.position[1]);
  if (n == "z") return static_cast<double>(s.position[2]);
  if (n == "nx") return static_cast<double>(s.normal[0]);
  if (n == "ny") return static_cast<double>(s.normal[1]);
  if (n == "nz") return static_cast<double>(s.normal[2]);
  if (n == "radius") return static_cast<double>(s.radius);
  const int channel = n == "red" ? 0 : n == "green" ? 1 : n == "blue" ? 2 : n == "alpha" ? 3 : -1;
  if (channel >= 0) {
    const double c = s.color[channel];
    return isFloatType(p.type) ? c / 255.0 : c;
  }
  return static_cast<double>(i % 100);  // unknown property: any value
}

struct PlyExtra {
  std::string before;  // header text of elements before the vertex element
  std::string after;   // header text of elements after it
  std::function<void(std::string&, PlyFormat)> bodyBefore, bodyAfter;
};

std::string makePly(PlyFormat format, const std::vector<PlyProperty>& properties,
                    const std::vector<Splat>& points, const PlyExtra& extra = {}) {
  std::string out = "ply\nformat ";
  out += format == PlyFormat::Ascii    ? "ascii"
         : format == PlyFormat::Little ? "binary_little_endian"
                                       : "binary_big_endian";
  out += " 1.0\ncomment written by readers_test\n" + extra.before;
  out += "element vertex " + std::to_string(points.size()) + "\n";
  for (const PlyProperty& p : properties) out += "property " + p.type + " " + p.name + "\n";
  out += extra.after + "end_header\n";
  if (extra.bodyBefore) extra.bodyBefore(out, format);
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (const PlyProperty& p : properties) {
      if (p.type.starts_with("list")) {
        // "list <count type> <item type>": i % 3 items.
        std::istringstream words(p.type);
        std::string list, countType, itemType;
        words >> list >> countType >> itemType;
        const std::size_t items = i % 3;
        putValue(out, countType, static_cast<double>(items), format);
        for (std::size_t k = 0; k < items; ++k)
          putValue(out, itemType, static_cast<double>(k), format);
      } else {
        putValue(out, p.type, vertexValue(points[i], p, i), format);
      }
    }
    if (format == PlyFormat::Ascii) out.back() = '\n';
  }
  if (extra.bodyAfter) extra.bodyAfter(out, format);
  return out;
}

void expectSamePoints(const PointCloud& cloud, const std::vector<Splat>& expected, bool normals,
                      bool colors, bool alpha, bool radii) {
  ASSERT_EQ(cloud.splats.size(), expected.size());
  EXPECT_EQ(cloud.hasNormals, normals);
  EXPECT_EQ(cloud.hasColors, colors);
  EXPECT_EQ(cloud.hasRadii, radii);
  for (std::size_t i = 0; i < expected.size(); ++i) {
    const Splat& got = cloud.splats[i];
    const Splat& want = expected[i];
    for (int k = 0; k < 3; ++k) {
      ASSERT_EQ(got.position[k], want.position[k]) << "point " << i << " axis " << k;
      if (normals) {
        ASSERT_NEAR(got.normal[k], want.normal[k], 1e-6) << "point " << i;
      } else {
        ASSERT_EQ(got.normal[k], 0.0f);
      }
    }
    for (int k = 0; k < 3; ++k) {
      ASSERT_EQ(got.color[k], colors ? want.color[k] : kDefaultGrey) << "point " << i;
    }
    ASSERT_EQ(got.color[3], alpha ? want.color[3] : 255);
    if (radii) {
      ASSERT_FLOAT_EQ(got.radius, want.radius);
    } else {
      ASSERT_EQ(got.radius, 0.0f);
    }
  }
}

const std::vector<PlyProperty> kXyz = {{"float", "x"}, {"float", "y"}, {"float", "z"}};

}  // namespace

// ------------------------------------------------------------------- PLY

TEST(PlyReader, AsciiPositionsOnly) {
  TempDir dir;
  const auto points = referencePoints(40);
  const auto file = dir.write("a.ply", makePly(PlyFormat::Ascii, kXyz, points));
  const PointCloud cloud = readPointCloud(file, defaults());
  expectSamePoints(cloud, points, false, false, false, false);
  EXPECT_EQ(cloud.source, file.string());
}

TEST(PlyReader, AllFormatsWithNormalsColoursRadiusRoundTrip) {
  TempDir dir;
  const auto points = referencePoints(300);
  const std::vector<PlyProperty> props = {{"float", "x"},     {"float", "y"},     {"float", "z"},
                                          {"float", "nx"},    {"float", "ny"},    {"float", "nz"},
                                          {"uchar", "red"},   {"uchar", "green"}, {"uchar", "blue"},
                                          {"uchar", "alpha"}, {"float", "radius"}};
  for (const PlyFormat format : {PlyFormat::Ascii, PlyFormat::Little, PlyFormat::Big}) {
    SCOPED_TRACE(static_cast<int>(format));
    const auto file = dir.write("full.ply", makePly(format, props, points));
    expectSamePoints(readPointCloud(file, defaults()), points, true, true, true, true);
  }
}

TEST(PlyReader, MixedOrderDoublesAndEveryScalarType) {
  TempDir dir;
  const auto points = referencePoints(120);
  // Unknown properties of every type are interleaved with the known ones.
  const std::vector<PlyProperty> props = {
      {"uchar", "blue"}, {"int16", "quality"}, {"double", "z"},  {"float64", "nx"},
      {"char", "flag"},  {"double", "x"},      {"uint", "id"},   {"ushort", "tag"},
      {"float32", "nz"}, {"uint8", "green"},   {"int", "label"}, {"double", "y"},
      {"short", "s"},    {"float", "ny"},      {"uchar", "red"}, {"float", "confidence"}};
  for (const PlyFormat format : {PlyFormat::Ascii, PlyFormat::Little, PlyFormat::Big}) {
    SCOPED_TRACE(static_cast<int>(format));
    const auto file = dir.write("mixed.PLY", makePly(format, props, points));
    expectSamePoints(readPointCloud(file, defaults()), points, true, true, false, false);
  }
}

TEST(PlyReader, FloatColoursInZeroToOne) {
  TempDir dir;
  const auto points = referencePoints(64);
  const std::vector<PlyProperty> props = {{"float", "x"},   {"float", "y"},      {"float", "z"},
                                          {"float", "red"}, {"double", "green"}, {"float", "blue"}};
  for (const PlyFormat format : {PlyFormat::Ascii, PlyFormat::Big}) {
    const auto file = dir.write("fc.ply", makePly(format, props, points));
    expectSamePoints(readPointCloud(file, defaults()), points, false, true, false, false);
  }
}

TEST(PlyReader, SkipsListPropertiesAndUnknownElements) {
  TempDir dir;
  const auto points = referencePoints(50);
  const std::vector<PlyProperty> props = {{"float", "x"},
                                          {"list uchar int", "neighbours"},
                                          {"float", "y"},
                                          {"list ushort float", "weights"},
                                          {"float", "z"}};
  PlyExtra extra;
  extra.before = "element material 2\nproperty uchar kind\nproperty list uchar float rgb\n";
  extra.after =
      "element edge 3\nproperty int vertex1\nproperty int vertex2\n"
      "element face 0\nproperty list uchar int vertex_indices\n";
  extra.bodyBefore = [](std::string& out, PlyFormat format) {
    for (int m = 0; m < 2; ++m) {
      putValue(out, "uchar", m, format);
      putValue(out, "uchar", 3, format);
      for (int k = 0; k < 3; ++k) putValue(out, "float", 0.5, format);
      if (format == PlyFormat::Ascii) out.back() = '\n';
    }
  };
  extra.bodyAfter = [](std::string& out, PlyFormat format) {
    for (int e = 0; e < 3; ++e) {
      putValue(out, "int", e, format);
      putValue(out, "int", e + 1, format);
      if (format == PlyFormat::Ascii) out.back() = '\n';
    }
  };
  for (const PlyFormat format : {PlyFormat::Ascii, PlyFormat::Little, PlyFormat::Big}) {
    SCOPED_TRACE(static_cast<int>(format));
    const auto file = dir.write("lists.ply", makePly(format, props, points, extra));
    expectSamePoints(readPointCloud(file, defaults()), points, false, false, false, false);
  }
}

TEST(PlyReader, CrLfHeaderAndBlankLines) {
  TempDir dir;
  const std::string text =
      "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\n"
      "property float z\r\nend_header\r\n1 2 3\r\n\r\n4 5 6\r\n";
  const PointCloud cloud = readPointCloud(dir.write("crlf.ply", text), defaults());
  ASSERT_EQ(cloud.splats.size(), 2u);
  EXPECT_EQ(cloud.splats[1].position[2], 6.0f);
}

TEST(PlyReader, ProgressIsReported) {
  TempDir dir;
  const auto points = referencePoints(200000);
  const auto file = dir.write("big.ply", makePly(PlyFormat::Little, kXyz, points));
  ReadOptions options = defaults();
  std::vector<std::pair<std::uint64_t, std::uint64_t>> calls;
  options.progress = [&](std::uint64_t done, std::uint64_t total) {
    calls.emplace_back(done, total);
  };
  const PointCloud cloud = readPointCloud(file, options);
  EXPECT_EQ(cloud.splats.size(), points.size());
  ASSERT_GE(calls.size(), 3u);
  EXPECT_EQ(calls.back().first, fs::file_size(file));
  EXPECT_EQ(calls.back().second, fs::file_size(file));
  for (std::size_t i = 1; i < calls.size(); ++i) EXPECT_GE(calls[i].first, calls[i - 1].first);
}

// --------------------------------------------------------------- PLY meshes

namespace {

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
double pointTriangleDistance(const std::array<double, 3>& p, const std::array<double, 3>& a,
                             const std::array<double, 3>& b, const std::array<double, 3>& c) {
  using V = std::array<double, 3>;
  const auto sub = [](const V& x, const V& y) { return V{x[0] - y[0], x[1] - y[1], x[2] - y[2]}; };
  const auto dot = [](const V& x, const V& y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; };
  const auto at = [&](double u, double v, double w) {
    return V{u * a[0] + v * b[0] + w * c[0], u * a[1] + v * b[1] + w * c[1],
             u * a[2] + v * b[2] + w * c[2]};
  };
  const V ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
  V closest;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  const V bp = sub(p, b);
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  const V cp = sub(p, c);
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  const double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
  if (d1 <= 0 && d2 <= 0) {
    closest = a;
  } else if (d3 >= 0 && d4 <= d3) {
    closest = b;
  } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const double v = d1 / (d1 - d3);
    closest = at(1 - v, v, 0);
  } else if (d6 >= 0 && d5 <= d6) {
    closest = c;
  } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const double w = d2 / (d2 - d6);
    closest = at(1 - w, 0, w);
  } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    closest = at(0, 1 - w, w);
  } else {
    const double denom = 1 / (va + vb + vc);
    const double v = vb * denom, w = vc * denom;
    closest = at(1 - v - w, v, w);
  }
  const V d = sub(p, closest);
  return std::sqrt(dot(d, d));
}

double distanceToMesh(const Splat& s, const TriangleMesh& mesh) {
  const std::array<double, 3> p{s.position[0], s.position[1], s.position[2]};
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : mesh.triangles) {
    best = std::min(best, pointTriangleDistance(p, mesh.vertices[t[0]], mesh.vertices[t[1]],
                                                mesh.vertices[t[2]]));
  }
  return best;
}

// An octahedron with a quad (split by fan triangulation) standing in for two faces.
const char* kOctahedronPly =
    "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
    "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
    "element face 7\nproperty list uchar int vertex_indices\nend_header\n"
    "1 0 0 255 0 0\n-1 0 0 0 255 0\n0 1 0 0 0 255\n0 -1 0 255 255 0\n0 0 1 255 255 255\n"
    "0 0 -1 0 0 0\n"
    "3 0 2 4\n3 2 1 4\n3 1 3 4\n3 3 0 4\n4 0 3 1 2\n3 2 2 5\n3 0 0 0\n";

}  // namespace

TEST(PlyMesh, SampledOnTheSurfaceWithOutwardNormalsAndVertexColours) {
  TempDir dir;
  ReadOptions options = defaults();
  options.meshSamplePoints = 5000;
  const PointCloud cloud = readPointCloud(dir.write("octa.ply", kOctahedronPly), options);
  ASSERT_EQ(cloud.splats.size(), 5000u);
  EXPECT_TRUE(cloud.hasNormals);
  EXPECT_TRUE(cloud.hasColors);
  EXPECT_TRUE(cloud.hasRadii);
  std::size_t upper = 0;
  for (const Splat& s : cloud.splats) {
    // Upper faces lie on |x|+|y|+z = 1; the bottom is the quad z = 0 (fan split).
    const double x = s.position[0], y = s.position[1], z = s.position[2];
    if (z > 1e-6) {
      ++upper;
      EXPECT_NEAR(std::abs(x) + std::abs(y) + z, 1.0, 1e-5);
      EXPECT_GT(s.normal[2], 0.5f);  // counter-clockwise faces seen from outside
    } else {
      EXPECT_NEAR(z, 0.0, 1e-6);
      EXPECT_NEAR(std::abs(s.normal[2]), 1.0f, 1e-6f);
    }
    EXPECT_GT(s.radius, 0.0f);
  }
  // Four upper faces of area sqrt(3)/2 each against a quad of area 2.
  const double upperShare = 4 * std::sqrt(3.0) / 2 / (4 * std::sqrt(3.0) / 2 + 2);
  EXPECT_NEAR(static_cast<double>(upper) / 5000.0, upperShare, 0.01);
  // Vertex colours are interpolated: the apex (0,0,1) is white.
  for (const Splat& s : cloud.splats) {
    if (s.position[2] > 0.98f) {
      EXPECT_GT(s.color[0], 240);
      EXPECT_GT(s.color[1], 240);
    }
  }
}

TEST(PlyMesh, RealSphereMeshSamplesLieOnItsTriangles) {
  REQUIRE_TEST_DATA();
  const fs::path file = dataDir() / "meshes" / "sphere.ply";
  ReadOptions options = defaults();
  options.meshSamplePoints = 3000;
  const PointCloud cloud = readPointCloud(file, options);
  ASSERT_EQ(cloud.splats.size(), 3000u);
  // Independent parse of the same mesh for the distance check.
  TriangleMesh mesh;
  std::ifstream in(file);
  std::string line;
  std::size_t vertices = 0, faces = 0;
  while (std::getline(in, line) && line.rfind("end_header", 0) != 0) {
    std::istringstream words(line);
    std::string a, b;
    std::size_t n = 0;
    words >> a >> b >> n;
    if (a == "element" && b == "vertex") vertices = n;
    if (a == "element" && b == "face") faces = n;
  }
  ASSERT_EQ(vertices, 162u);
  ASSERT_EQ(faces, 320u);
  for (std::size_t i = 0; i < vertices; ++i) {
    std::getline(in, line);
    std::istringstream words(line);
    std::array<double, 3> v{};
    words >> v[0] >> v[1] >> v[2];
    mesh.vertices.push_back(v);
  }
  for (std::size_t i = 0; i < faces; ++i) {
    std::getline(in, line);
    std::istringstream words(line);
    std::uint32_t n = 0, a = 0, b = 0, c = 0;
    words >> n >> a >> b >> c;
    mesh.triangles.push_back({a, b, c});
  }
  double maxDistance = 0;
  for (std::size_t i = 0; i < cloud.splats.size(); i += 3) {
    maxDistance = std::max(maxDistance, distanceToMesh(cloud.splats[i], mesh));
  }
  EXPECT_LT(maxDistance, 1e-5 * 2.0);  // the sphere spans about 2 units
}

TEST(PlyMesh, RealColouredTetrahedronWithFaceColoursAndEdges) {
  REQUIRE_TEST_DATA();
  ReadOptions options = defaults();
  options.meshSamplePoints = 1000;
  const PointCloud cloud = readPointCloud(dataDir() / "meshes" / "colored_tetra.ply", options);
  ASSERT_EQ(cloud.splats.size(), 1000u);
  EXPECT_TRUE(cloud.hasColors);
  for (const Splat& s : cloud.splats) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_GE(s.position[k], -1e-6f);
      EXPECT_LE(s.position[k], 1.0f + 1e-6f);
    }
  }
}

// ---------------------------------------------------------- real PLY files

TEST(RealFiles, BuildingPlyCountsAndValues) {
  REQUIRE_TEST_DATA();
  const PointCloud cloud = readPointCloud(dataDir() / "points_3" / "building.ply", defaults());
  ASSERT_EQ(cloud.splats.size(), 100000u);  // "element vertex 100000"
  EXPECT_TRUE(cloud.hasNormals);
  EXPECT_FALSE(cloud.hasColors);
  const Splat& first = cloud.splats.front();  // "8.19821 -21.7553 7.88123 0 0 1 16"
  EXPECT_FLOAT_EQ(first.position[0], 8.19821f);
  EXPECT_FLOAT_EQ(first.position[1], -21.7553f);
  EXPECT_FLOAT_EQ(first.position[2], 7.88123f);
  EXPECT_FLOAT_EQ(first.normal[2], 1.0f);
  const Splat& fourth = cloud.splats[3];  // "-3.08065 21.6219 -1.45825 0.0214952 ..."
  EXPECT_FLOAT_EQ(fourth.position[0], -3.08065f);
  EXPECT_NEAR(fourth.normal[1], 0.999419f, 1e-5f);
  // Bounding box by awk over the body.
  float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
  for (const Splat& s : cloud.splats) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], s.position[k]);
      hi[k] = std::max(hi[k], s.position[k]);
    }
  }
  EXPECT_FLOAT_EQ(lo[0], -7.46581f);
  EXPECT_FLOAT_EQ(lo[1], -32.6452f);
  EXPECT_FLOAT_EQ(lo[2], -3.15146f);
  EXPECT_FLOAT_EQ(hi[0], 8.33086f);
  EXPECT_FLOAT_EQ(hi[1], 22.1926f);
  EXPECT_FLOAT_EQ(hi[2], 14.761f);
}

TEST(RealFiles, BinaryLittleEndianB9Training) {
  REQUIRE_TEST_DATA();
  const PointCloud cloud = readPointCloud(dataDir() / "points_3" / "b9_training.ply", defaults());
  ASSERT_EQ(cloud.splats.size(), 22300u);  // 22300 records of 31 bytes after a 239-byte header
  EXPECT_TRUE(cloud.hasColors);
  EXPECT_FALSE(cloud.hasNormals);
  // First record (doubles at byte 239): 596732.4375 243629.125 76.76165008544922, rgb 0 0 0.
  EXPECT_EQ(cloud.splats[0].position[0], 596732.4375f);
  EXPECT_EQ(cloud.splats[0].position[1], 243629.125f);
  EXPECT_FLOAT_EQ(cloud.splats[0].position[2], 76.76165f);
  EXPECT_EQ(cloud.splats[0].color[0], 0);
}

TEST(RealFiles, BunnyOffHeaderCountsAndVertices) {
  REQUIRE_TEST_DATA();
  const fs::path file = dataDir() / "meshes" / "bunny00.off";
  const TriangleMesh mesh = readOffMesh(file, defaults());
  ASSERT_EQ(mesh.vertices.size(), 37706u);  // header "37706 75408 0"
  EXPECT_EQ(mesh.faces, 75408u);
  EXPECT_EQ(mesh.triangles.size(), 75408u);  // all triangles
  EXPECT_DOUBLE_EQ(mesh.vertices[0][0], -0.167662);
  EXPECT_DOUBLE_EQ(mesh.vertices[0][1], -0.411917);
  EXPECT_DOUBLE_EQ(mesh.vertices[0][2], -0.0732205);
  EXPECT_DOUBLE_EQ(mesh.vertices.back()[1], -0.490115);  // line 37709: "-0.157114 -0.490115 ..."
  const auto& first = mesh.triangles.front();            // "3  28801 33329 8688"
  EXPECT_EQ(first[0], 28801u);
  EXPECT_EQ(first[2], 8688u);
  const auto& last = mesh.triangles.back();  // "3  37478 37477 5564"
  EXPECT_EQ(last[0], 37478u);
  EXPECT_EQ(last[1], 37477u);
  EXPECT_EQ(last[2], 5564u);

  ReadOptions options = defaults();
  options.meshSamplePoints = 20000;
  const PointCloud cloud = readPointCloud(file, options);
  ASSERT_EQ(cloud.splats.size(), 20000u);
  // Bounding box of the vertices (awk): x -0.498959..0.49922, y -0.493434..0.493767, z
  // -0.38649..0.386086.
  for (const Splat& s : cloud.splats) {
    EXPECT_GE(s.position[0], -0.498959f - 1e-6f);
    EXPECT_LE(s.position[0], 0.49922f + 1e-6f);
    EXPECT_GE(s.position[2], -0.38649f - 1e-6f);
    EXPECT_LE(s.position[2], 0.386086f + 1e-6f);
  }
  // A few samples checked against all 75408 triangles.
  for (std::size_t i = 0; i < cloud.splats.size(); i += 997) {
    EXPECT_LT(distanceToMesh(cloud.splats[i], mesh), 1e-5) << "sample " << i;
  }
  // Deterministic for a seed.
  const PointCloud again = readPointCloud(file, options);
  EXPECT_EQ(0, std::memcmp(again.splats.data(), cloud.splats.data(), 20000 * sizeof(Splat)));
}

TEST(RealFiles, XyzWithAndWithoutNormals) {
  REQUIRE_TEST_DATA();
  const PointCloud kitten = readPointCloud(dataDir() / "points_3" / "kitten.xyz", defaults());
  ASSERT_EQ(kitten.splats.size(), 5210u);  // wc -l
  EXPECT_TRUE(kitten.hasNormals);
  EXPECT_FLOAT_EQ(kitten.splats[0].position[0], -0.0721898f);
  EXPECT_NEAR(kitten.splats[0].normal[1], 0.937712f, 1e-5f);

  const PointCloud oneK = readPointCloud(dataDir() / "points_3" / "oneK.xyz", defaults());
  ASSERT_EQ(oneK.splats.size(), 1000u);
  EXPECT_FALSE(oneK.hasNormals);
  EXPECT_FLOAT_EQ(oneK.splats[0].position[2], 0.228394f);

  const PointCloud sphere =
      readPointCloud(dataDir() / "points_3" / "sphere_20k_normal.xyz", defaults());
  ASSERT_EQ(sphere.splats.size(), 21000u);  // trailing blanks on every line
  EXPECT_TRUE(sphere.hasNormals);
}

TEST(RealFiles, EveryCgalPointFileReads) {
  REQUIRE_TEST_DATA();
  std::size_t files = 0;
  for (const auto& entry : fs::directory_iterator(dataDir() / "points_3")) {
    const std::string ext = entry.path().extension().string();
    if (ext != ".ply" && ext != ".xyz" && ext != ".off") continue;
    SCOPED_TRACE(entry.path().string());
    ReadOptions options = defaults();
    options.meshSamplePoints = 500;
    if (entry.path().filename() == "triangles.xyz") {
      // A triangle soup (9 coordinates per line), not points: refused clearly.
      expectInputError([&] { readPointCloud(entry.path(), options); },
                       {"triangles.xyz", "line 1", "9-column"});
      continue;
    }
    const PointCloud cloud = readPointCloud(entry.path(), options);
    EXPECT_FALSE(cloud.splats.empty());
    ++files;
  }
  EXPECT_GT(files, 20u);
}

// ------------------------------------------------------------- XYZ / PTS

TEST(XyzReader, LayoutsByColumnCount) {
  TempDir dir;
  {
    const auto cloud = readPointCloud(
        dir.write("p.xyz", "# comment\n1 2 3\n  4\t5 6  # trailing\n\n7,8,9\n"), defaults());
    ASSERT_EQ(cloud.splats.size(), 3u);
    EXPECT_EQ(cloud.splats[2].position[1], 8.0f);
    EXPECT_FALSE(cloud.hasNormals);
    EXPECT_FALSE(cloud.hasColors);
    EXPECT_EQ(cloud.splats[0].color[0], kDefaultGrey);
  }
  {
    const auto cloud =
        readPointCloud(dir.write("n.xyz", "0 0 0 0 0 1\n1 0 0 0.6 0.8 0\n"), defaults());
    ASSERT_EQ(cloud.splats.size(), 2u);
    EXPECT_TRUE(cloud.hasNormals);
    EXPECT_FALSE(cloud.hasColors);
    EXPECT_FLOAT_EQ(cloud.splats[1].normal[1], 0.8f);
  }
  {
    const auto cloud =
        readPointCloud(dir.write("c.txt", "0 0 0 255 0 10\n1 0 0 20 30 40\n"), defaults());
    EXPECT_FALSE(cloud.hasNormals);
    EXPECT_TRUE(cloud.hasColors);
    EXPECT_EQ(cloud.splats[0].color[0], 255);
    EXPECT_EQ(cloud.splats[1].color[2], 40);
  }
  {
    const auto cloud = readPointCloud(dir.write("i.xyz", "1 2 3 0.5\n4 5 6 0.7\n"), defaults());
    ASSERT_EQ(cloud.splats.size(), 2u);
    EXPECT_FALSE(cloud.hasColors);
  }
  {
    const auto cloud = readPointCloud(
        dir.write("nc.xyz", "0 0 0 0 0 -1 10 20 30\n1 1 1 1 0 0 40 50 60\n"), defaults());
    EXPECT_TRUE(cloud.hasNormals);
    EXPECT_TRUE(cloud.hasColors);
    EXPECT_EQ(cloud.splats[1].color[1], 50);
    EXPECT_FLOAT_EQ(cloud.splats[0].normal[2], -1.0f);
  }
  {
    const auto cloud = readPointCloud(
        dir.write("cn.xyz", "0 0 0 10 20 30 0 0 -1\n1 1 1 40 50 60 1 0 0\n"), defaults());
    EXPECT_TRUE(cloud.hasNormals);
    EXPECT_TRUE(cloud.hasColors);
    EXPECT_EQ(cloud.splats[0].color[2], 30);
    EXPECT_FLOAT_EQ(cloud.splats[1].normal[0], 1.0f);
  }
}

TEST(XyzReader, PtsWithCountAndIntensity) {
  TempDir dir;
  const auto cloud = readPointCloud(
      dir.write("scan.PTS", "3\n1.5 2 3 -120 255 0 0\n4 5 6 17 0 255 0\n7 8 9 0 0 0 255\n"),
      defaults());
  ASSERT_EQ(cloud.splats.size(), 3u);
  EXPECT_TRUE(cloud.hasColors);
  EXPECT_EQ(cloud.splats[0].position[0], 1.5f);
  EXPECT_EQ(cloud.splats[1].color[1], 255);
  EXPECT_EQ(cloud.splats[2].color[0], 0);
  EXPECT_EQ(cloud.splats[2].color[2], 255);
}

// ------------------------------------------------------------------ LAS

namespace {

struct LasPoint {
  std::int32_t x, y, z;
  std::uint16_t r, g, b;
};

template <class T>
void putLe(std::string& out, std::size_t at, T value) {
  static_assert(std::endian::native == std::endian::little, "test writer assumes a LE host");
  std::memcpy(out.data() + at, &value, sizeof(T));
}

// A LAS file of the given version and point format with a VLR and two extra
// bytes per record; scale 0.01 and offset (1000, 2000, 50).
std::string makeLas(int minor, int format, const std::vector<LasPoint>& points,
                    std::uint8_t formatFlags = 0) {
  const std::size_t headerSize = minor >= 4 ? 375 : minor == 3 ? 235 : 227;
  const std::size_t baseLength[] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
  const int rgbAt[] = {-1, -1, 20, 28, -1, 28, -1, 30, 30, -1, 30};
  const std::size_t recordLength = baseLength[format] + 2;
  const std::size_t vlrSize = 54 + 10;
  std::string out(headerSize + vlrSize, '\0');
  std::memcpy(out.data(), "LASF", 4);
  out[24] = 1;
  out[25] = static_cast<char>(minor);
  putLe<std::uint16_t>(out, 94, static_cast<std::uint16_t>(headerSize));
  putLe<std::uint32_t>(out, 96, static_cast<std::uint32_t>(headerSize + vlrSize));
  putLe<std::uint32_t>(out, 100, 1);
  out[104] = static_cast<char>(format | formatFlags);
  putLe<std::uint16_t>(out, 105, static_cast<std::uint16_t>(recordLength));
  putLe<std::uint32_t>(out, 107, format >= 6 ? 0u : static_cast<std::uint32_t>(points.size()));
  const double scale[3] = {0.01, 0.01, 0.001}, offset[3] = {1000, 2000, 50};
  for (int k = 0; k < 3; ++k) {
    putLe<double>(out, 131 + 8 * static_cast<std::size_t>(k), scale[k]);
    putLe<double>(out, 155 + 8 * static_cast<std::size_t>(k), offset[k]);
  }
  if (minor >= 4) putLe<std::uint64_t>(out, 247, points.size());
  std::memcpy(out.data() + headerSize + 2, "pointillist test", 16);  // VLR user id
  putLe<std::uint16_t>(out, headerSize + 20, 10);                    // VLR payload size
  for (const LasPoint& p : points) {
    std::string record(recordLength, '\x5a');
    putLe<std::int32_t>(record, 0, p.x);
    putLe<std::int32_t>(record, 4, p.y);
    putLe<std::int32_t>(record, 8, p.z);
    if (rgbAt[format] >= 0) {
      const auto at = static_cast<std::size_t>(rgbAt[format]);
      putLe<std::uint16_t>(record, at, p.r);
      putLe<std::uint16_t>(record, at + 2, p.g);
      putLe<std::uint16_t>(record, at + 4, p.b);
    }
    out += record;
  }
  return out;
}

std::vector<LasPoint> lasPoints(std::size_t n, bool sixteenBit) {
  std::vector<LasPoint> points;
  for (std::size_t i = 0; i < n; ++i) {
    const auto k = static_cast<std::int32_t>(i);
    const auto c = static_cast<std::uint16_t>((i * 41) % 256);
    const auto m = static_cast<std::uint16_t>(sixteenBit ? 256 : 1);
    points.push_back({k * 37 - 5000, -k * 13 + 77, k * 1001, static_cast<std::uint16_t>(c * m),
                      static_cast<std::uint16_t>((255 - c) * m),
                      static_cast<std::uint16_t>(((c * 7) % 256) * m)});
  }
  return points;
}

}  // namespace

TEST(LasReader, FormatsAndVersionsWithScaleAndOffset) {
  TempDir dir;
  // Every version 1.0-1.4 and point format 0-10 the README claims (4, 5, 9 and
  // 10 carry waveform packets, which are skipped).
  const std::vector<std::pair<int, int>> cases = {
      {0, 0}, {0, 1}, {1, 0}, {1, 1}, {2, 0}, {2, 1}, {2, 2}, {2, 3}, {3, 0}, {3, 3},
      {3, 4}, {3, 5}, {4, 1}, {4, 2}, {4, 6}, {4, 7}, {4, 8}, {4, 9}, {4, 10}};
  for (const auto& [minor, format] : cases) {
    SCOPED_TRACE("LAS 1." + std::to_string(minor) + " format " + std::to_string(format));
    for (const bool sixteen : {true, false}) {
      const auto points = lasPoints(500, sixteen);
      const auto file = dir.write("p.LAS", makeLas(minor, format, points));
      const PointCloud cloud = readPointCloud(file, defaults());
      ASSERT_EQ(cloud.splats.size(), points.size());
      const bool rgb =
          format == 2 || format == 3 || format == 5 || format == 7 || format == 8 || format == 10;
      EXPECT_EQ(cloud.hasColors, rgb);
      EXPECT_FALSE(cloud.hasNormals);
      for (std::size_t i = 0; i < points.size(); ++i) {
        const Splat& s = cloud.splats[i];
        ASSERT_FLOAT_EQ(s.position[0], static_cast<float>(points[i].x * 0.01 + 1000));
        ASSERT_FLOAT_EQ(s.position[1], static_cast<float>(points[i].y * 0.01 + 2000));
        ASSERT_FLOAT_EQ(s.position[2], static_cast<float>(points[i].z * 0.001 + 50));
        const int m = sixteen ? 256 : 1;
        ASSERT_EQ(s.color[0], rgb ? points[i].r / m : kDefaultGrey);
        ASSERT_EQ(s.color[1], rgb ? points[i].g / m : kDefaultGrey);
        ASSERT_EQ(s.color[2], rgb ? points[i].b / m : kDefaultGrey);
      }
    }
  }
}

// Streamed in blocks (the out-of-core preprocess) LAS gives the same points,
// colours scaled as a whole read scales them: 16-bit colours are found by a
// first pass, 8-bit ones stay.
namespace {

// A file read through streamPointClouds in blocks of at most `block` points.
struct Streamed {
  std::vector<Splat> splats;
  std::uint64_t count = 0;
  PointCloud flags;
};
Streamed readStreamed(const std::filesystem::path& file, std::size_t block) {
  ReadOptions streaming = defaults();
  streaming.sinkBlock = block;
  Streamed out;
  out.flags = streamPointClouds(
      {file}, streaming,
      [&](std::span<const Splat> part) {
        EXPECT_LE(part.size(), block);
        out.splats.insert(out.splats.end(), part.begin(), part.end());
      },
      out.count);
  return out;
}

}  // namespace

TEST(LasReader, StreamedAsReadWhole) {
  TempDir dir;
  for (const bool sixteen : {true, false}) {
    const auto file =
        dir.write(sixteen ? "16.las" : "8.las", makeLas(2, 3, lasPoints(3000, sixteen)));
    const PointCloud whole = readPointCloud(file, defaults());
    const Streamed streamed = readStreamed(file, 500);
    ASSERT_EQ(streamed.splats.size(), whole.splats.size());
    EXPECT_EQ(streamed.count, whole.splats.size());
    EXPECT_EQ(std::memcmp(streamed.splats.data(), whole.splats.data(),
                          streamed.splats.size() * sizeof(Splat)),
              0);
    EXPECT_TRUE(streamed.flags.hasColors);
  }
}

TEST(LasReader, RefusesLazAndBadHeaders) {
  TempDir dir;
  const auto points = lasPoints(10, true);
  expectInputError(
      [&] { readPointCloud(dir.write("c.las", makeLas(2, 3, points, 0x80)), defaults()); },
      {"c.las", "byte 104", "LAZ"});
  expectInputError([&] { readPointCloud(dir.write("d.laz", "whatever"), defaults()); },
                   {"d.laz", "LAZ"});
  std::string bad = makeLas(2, 1, points);
  bad[0] = 'X';
  expectInputError([&] { readPointCloud(dir.write("sig.las", bad), defaults()); },
                   {"sig.las", "byte 0", "LASF"});
  std::string version = makeLas(2, 1, points);
  version[25] = 9;
  expectInputError([&] { readPointCloud(dir.write("ver.las", version), defaults()); },
                   {"ver.las", "byte 24", "1.9"});
  std::string shortRecord = makeLas(2, 3, points);
  putLe<std::uint16_t>(shortRecord, 105, 30);
  expectInputError([&] { readPointCloud(dir.write("len.las", shortRecord), defaults()); },
                   {"len.las", "byte 105", "too short"});
  std::string zeroScale = makeLas(2, 0, points);
  putLe<double>(zeroScale, 139, 0.0);
  expectInputError([&] { readPointCloud(dir.write("scale.las", zeroScale), defaults()); },
                   {"scale.las", "byte 139", "scale"});
  expectInputError([&] { readPointCloud(dir.write("tiny.las", "LASF\1\2"), defaults()); },
                   {"tiny.las", "truncated LAS header"});
}

TEST(LasReader, TruncatedPointData) {
  TempDir dir;
  const auto points = lasPoints(100, true);
  std::string bytes = makeLas(2, 3, points);
  // Header 227 + VLR 64 = 291, records of 36 bytes; cut inside record 60.
  bytes.resize(291 + 60 * 36 + 10);
  expectInputError([&] { readPointCloud(dir.write("cut.las", bytes), defaults()); },
                   {"cut.las", "byte " + std::to_string(291 + 60 * 36),
                    "truncated point data (expected 100 points, got 60)"});
  // 1.4 with a point count far beyond the file: refused, not allocated.
  std::string absurd = makeLas(4, 6, points);
  putLe<std::uint64_t>(absurd, 247, std::uint64_t{1} << 40);
  expectInputError([&] { readPointCloud(dir.write("absurd.las", absurd), defaults()); },
                   {"absurd.las", "expected 1099511627776 points, got 100"});
}

// ------------------------------------------------------------------ OFF

TEST(OffReader, VariantsAndComments) {
  TempDir dir;
  ReadOptions options = defaults();
  options.meshSamplePoints = 400;
  // Counts on the keyword line, a comment, a quad.
  auto cloud = readPointCloud(
      dir.write("q.off", "OFF 4 1 0\n# unit square\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"),
      options);
  ASSERT_EQ(cloud.splats.size(), 400u);
  for (const Splat& s : cloud.splats) {
    EXPECT_EQ(s.position[2], 0.0f);
    EXPECT_EQ(s.normal[2], 1.0f);
    EXPECT_EQ(s.color[0], kDefaultGrey);
  }
  // COFF with vertex colours in 0..255.
  cloud = readPointCloud(dir.write("c.off",
                                   "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 255 0 0 255\n"
                                   "0 1 0 255 0 0 255\n3 0 1 2\n"),
                         options);
  EXPECT_TRUE(cloud.hasColors);
  EXPECT_EQ(cloud.splats[7].color[0], 255);
  EXPECT_EQ(cloud.splats[7].color[1], 0);
  // Face colours as 0..1 floats.
  cloud = readPointCloud(
      dir.write("f.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 0.0 1.0 0.0\n"), options);
  EXPECT_TRUE(cloud.hasColors);
  EXPECT_EQ(cloud.splats[0].color[1], 255);
  // NOFF without faces is a point cloud with normals.
  cloud = readPointCloud(dir.write("n.off", "NOFF\n2 0 0\n0 0 0 0 0 2\n1 1 1 1 0 0\n"), options);
  ASSERT_EQ(cloud.splats.size(), 2u);
  EXPECT_TRUE(cloud.hasNormals);
  EXPECT_FLOAT_EQ(cloud.splats[0].normal[2], 1.0f);  // normalised
}

TEST(MeshSampler, AreaWeightingOneToThree) {
  TriangleMesh mesh;
  // Two separate right triangles of area 1 and 3.
  const double s1 = std::sqrt(2.0), s3 = std::sqrt(6.0);
  mesh.vertices = {{0, 0, 0}, {s1, 0, 0}, {0, s1, 0}, {10, 0, 0}, {10 + s3, 0, 0}, {10, s3, 0}};
  mesh.triangles = {{0, 1, 2}, {3, 4, 5}};
  const std::size_t n = 40000;
  const PointCloud cloud = sampleMesh(mesh, n, 7, "two.off");
  ASSERT_EQ(cloud.splats.size(), n);
  std::size_t small = 0;
  for (const Splat& s : cloud.splats) small += s.position[0] < 5.0f ? 1 : 0;
  // Binomial(n, 1/4): sigma = sqrt(n * 3/16) ~ 87; allow 3 sigma.
  EXPECT_NEAR(static_cast<double>(small), n / 4.0, 3 * std::sqrt(n * 3.0 / 16.0));
  // Every point inside its triangle.
  for (const Splat& s : cloud.splats) {
    const double x = s.position[0], y = s.position[1];
    if (x < 5) {
      EXPECT_LE(x + y, s1 + 1e-6);
    } else {
      EXPECT_LE((x - 10) + y, s3 + 1e-5);
    }
    EXPECT_GE(y, 0.0);
  }
  // Radius from the sampling density: sqrt(3 * area / (pi * n)).
  EXPECT_NEAR(cloud.splats[0].radius,
              std::sqrt(3 * 4.0 / (std::numbers::pi * static_cast<double>(n))), 1e-7);
}

// The sampler draws its random numbers on one thread and makes the points on
// all: the points must be those of one walk through the stream and the
// cumulative areas, bit for bit, across its chunks (2^18 points) and blocks
// (2^14), with a degenerate triangle in the list, and with vertex colours.
TEST(MeshSampler, PointsOnAllThreadsEqualOneSerialWalk) {
  TriangleMesh mesh;
  Rng shape(3);
  for (int t = 0; t < 500; ++t) {
    const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
    for (int v = 0; v < 3; ++v)
      mesh.vertices.push_back({shape.uniform(0, 10), shape.uniform(0, 10), shape.uniform(0, 1)});
    mesh.vertexColors.push_back({static_cast<std::uint8_t>(t), 10, 200, 255});
    mesh.vertexColors.push_back({0, static_cast<std::uint8_t>(t), 20, 255});
    mesh.vertexColors.push_back({30, 40, static_cast<std::uint8_t>(t), 255});
    mesh.triangles.push_back({base, base + 1, t == 7 ? base : base + 2});  // one degenerate
  }
  const std::size_t n = (std::size_t{1} << 20) + 12345;  // four chunks and a part
  const PointCloud cloud = sampleMesh(mesh, n, 11, "many.off");
  ASSERT_EQ(cloud.splats.size(), n);

  // The serial walk, as the sampler's documentation describes it.
  std::vector<std::uint32_t> used;
  std::vector<double> cumulative;
  double total = 0.0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const auto& a = mesh.vertices[tri[0]];
    const double area =
        0.5 * pointillist::length(pointillist::cross(pointillist::sub(mesh.vertices[tri[1]], a),
                                                     pointillist::sub(mesh.vertices[tri[2]], a)));
    if (!(area > 0.0)) continue;  // the others are far above the sampler's threshold
    total += area;
    used.push_back(static_cast<std::uint32_t>(t));
    cumulative.push_back(total);
  }
  ASSERT_EQ(used.size(), 499u);
  Rng rng(11);
  const double step = total / static_cast<double>(n);
  std::size_t u = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double target = (static_cast<double>(i) + rng.uniform()) * step;
    while (u + 1 < used.size() && cumulative[u] <= target) ++u;
    const auto& tri = mesh.triangles[used[u]];
    const auto& a = mesh.vertices[tri[0]];
    const auto& b = mesh.vertices[tri[1]];
    const auto& c = mesh.vertices[tri[2]];
    const double r1 = std::sqrt(rng.uniform());
    const double r2 = rng.uniform();
    const double wa = 1.0 - r1, wb = r1 * (1.0 - r2), wc = r1 * r2;
    for (std::size_t k = 0; k < 3; ++k) {
      const auto want = static_cast<float>(a[k] * wa + b[k] * wb + c[k] * wc);
      ASSERT_EQ(cloud.splats[i].position[k], want) << "point " << i << " axis " << k;
    }
    const double red = wa * mesh.vertexColors[tri[0]][0] + wb * mesh.vertexColors[tri[1]][0] +
                       wc * mesh.vertexColors[tri[2]][0];
    ASSERT_EQ(cloud.splats[i].color[0], detail::colorFromByte(red)) << "point " << i;
    const auto normal = pointillist::cross(pointillist::sub(b, a), pointillist::sub(c, a));
    const double len = pointillist::length(normal);
    for (std::size_t k = 0; k < 3; ++k)
      ASSERT_EQ(cloud.splats[i].normal[k], static_cast<float>(normal[k] / len)) << "point " << i;
  }
}

TEST(MeshSampler, SkipsDegenerateTrianglesAndRejectsAllDegenerate) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}, {3, 0, 0}};
  mesh.triangles = {{0, 3, 4}, {0, 1, 2}, {1, 1, 2}};  // collinear, good, repeated vertex
  const PointCloud cloud = sampleMesh(mesh, 1000, 1, "deg.off");
  for (const Splat& s : cloud.splats) {
    EXPECT_LE(s.position[0] + s.position[1], 1.0f + 1e-6f);
    EXPECT_EQ(s.normal[2], 1.0f);
  }
  mesh.triangles = {{0, 3, 4}, {1, 1, 2}};
  expectInputError([&] { sampleMesh(mesh, 10, 1, "deg.off"); }, {"deg.off", "degenerate"});
  EXPECT_THROW(sampleMesh(mesh, 0, 1, "deg.off"), UsageError);
}

// ------------------------------------------------------------------ merging

TEST(ReadPointClouds, ConcatenatesAndAndsFlags) {
  TempDir dir;
  const auto a = dir.write("a.xyz", "0 0 0 0 0 1\n1 0 0 0 0 1\n");
  const auto b = dir.write("b.xyz", "5 5 5 10 20 30\n");
  std::uint64_t lastDone = 0, lastTotal = 0;
  ReadOptions options = defaults();
  options.progress = [&](std::uint64_t done, std::uint64_t total) {
    EXPECT_GE(done, lastDone);
    lastDone = done;
    lastTotal = total;
  };
  const PointCloud merged = readPointClouds({a, b}, options);
  ASSERT_EQ(merged.splats.size(), 3u);
  EXPECT_FALSE(merged.hasNormals);
  EXPECT_FALSE(merged.hasColors);
  EXPECT_EQ(merged.splats[0].normal[2], 1.0f);  // kept per point
  EXPECT_EQ(merged.splats[2].normal[2], 0.0f);  // marked missing
  EXPECT_EQ(merged.splats[2].color[1], 20);     // b's colours survive the AND
  EXPECT_NE(merged.source.find("a.xyz"), std::string::npos);
  EXPECT_NE(merged.source.find("b.xyz"), std::string::npos);
  EXPECT_EQ(lastTotal, fs::file_size(a) + fs::file_size(b));
  EXPECT_EQ(lastDone, lastTotal);
  EXPECT_THROW(readPointClouds({}, options), UsageError);
}

// ------------------------------------------------------------------ bad input

TEST(BadInput, MissingUnknownAndEmpty) {
  TempDir dir;
  expectInputError([&] { readPointCloud(dir.path() / "nothere.ply", defaults()); },
                   {"nothere.ply", "no such file"});
  expectInputError([&] { readPointCloud(dir.write("x.obj", "v 1 2 3\n"), defaults()); },
                   {"x.obj", "unknown file type"});
  expectInputError([&] { readPointCloud(dir.write("e.xyz", "# nothing\n\n"), defaults()); },
                   {"e.xyz", "no points"});
  expectInputError(
      [&] {
        readPointCloud(dir.write("e.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                                 "property float y\nproperty float z\nend_header\n"),
                       defaults());
      },
      {"e.ply", "no points"});
  expectInputError([&] { readPointCloud(dir.write("e.off", ""), defaults()); }, {"e.off", "empty"});
}

TEST(BadInput, PlyHeaders) {
  TempDir dir;
  const auto bad = [&](const std::string& name, const std::string& text,
                       const std::vector<std::string>& needles) {
    expectInputError([&] { readPointCloud(dir.write(name, text), defaults()); }, needles);
  };
  bad("magic.ply", "plx\nformat ascii 1.0\n", {"magic.ply", "line 1", "not a PLY"});
  bad("fmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n", {"fmt.ply", "line 2"});
  bad("type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
      {"type.ply", "line 4"});
  bad("noend.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
      {"noend.ply", "line 4", "end_header"});
  bad("noxyz.ply",
      "ply\nformat ascii 1.0\ncomment c\nelement vertex 1\nproperty float x\nend_header\n1\n",
      {"noxyz.ply", "line 4", "x, y or z"});
  bad("count.ply", "ply\nformat ascii 1.0\nelement vertex many\nend_header\n",
      {"count.ply", "line 3"});
  bad("novertex.ply", "ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n1\n",
      {"novertex.ply", "line 5", "vertex"});
}

TEST(BadInput, PlyBodies) {
  TempDir dir;
  const auto points = referencePoints(10);
  const std::string ascii = makePly(PlyFormat::Ascii, kXyz, points);
  const std::size_t headerLines = 8;  // ply, format, comment, element, 3 properties, end_header
  // Truncated ascii body: 7 of 10 lines.
  {
    std::string text = ascii;
    std::size_t pos = 0;
    for (std::size_t i = 0; i < headerLines + 7; ++i) pos = text.find('\n', pos) + 1;
    text.resize(pos);
    expectInputError([&] { readPointCloud(dir.write("cut.ply", text), defaults()); },
                     {"cut.ply", "line " + std::to_string(headerLines + 7),
                      "truncated vertex data (expected 10 vertices, got 7)"});
  }
  // A value missing on line 3 of the body, an extra value on another, trailing lines.
  {
    std::string text = ascii;
    const std::size_t line3 = [&] {
      std::size_t pos = 0;
      for (std::size_t i = 0; i < headerLines + 2; ++i) pos = text.find('\n', pos) + 1;
      return pos;
    }();
    const std::size_t lastBlank = text.rfind(' ', text.find('\n', line3));
    std::string missing = text;
    missing.erase(lastBlank, text.find('\n', line3) - lastBlank);
    expectInputError([&] { readPointCloud(dir.write("few.ply", missing), defaults()); },
                     {"few.ply", "line " + std::to_string(headerLines + 3), "too few values"});
    std::string extra = text;
    extra.insert(text.find('\n', line3), " 42");
    expectInputError([&] { readPointCloud(dir.write("many.ply", extra), defaults()); },
                     {"many.ply", "line " + std::to_string(headerLines + 3), "more values"});
    expectInputError([&] { readPointCloud(dir.write("tail.ply", text + "1 2 3\n"), defaults()); },
                     {"tail.ply", "line " + std::to_string(headerLines + 11), "more data"});
    std::string word = text;
    word.replace(line3, 1, "x");
    expectInputError([&] { readPointCloud(dir.write("word.ply", word), defaults()); },
                     {"word.ply", "line " + std::to_string(headerLines + 3), "not a number"});
  }
  // Truncated binary body: byte offset of the first incomplete record.
  {
    const std::string binary = makePly(PlyFormat::Little, kXyz, points);
    const std::size_t header = binary.size() - 10 * 12;
    const std::string cut = binary.substr(0, header + 4 * 12 + 5);
    expectInputError([&] { readPointCloud(dir.write("bin.ply", cut), defaults()); },
                     {"bin.ply", "byte " + std::to_string(header + 4 * 12),
                      "truncated vertex data (expected 10 vertices, got 4)"});
    expectInputError(
        [&] {
          readPointCloud(dir.write("binextra.ply", binary + std::string(24, '\x7f')), defaults());
        },
        {"binextra.ply", "byte " + std::to_string(binary.size()), "after the last element"});
  }
  // A count far beyond the file: no huge allocation, a truncation error.
  {
    std::string text = makePly(PlyFormat::Big, kXyz, points);
    const std::string from = "element vertex 10\n";
    text.replace(text.find(from), from.size(), "element vertex 4000000000000\n");
    expectInputError([&] { readPointCloud(dir.write("absurd.ply", text), defaults()); },
                     {"absurd.ply", "byte", "expected 4000000000000 vertices, got 10"});
  }
}

TEST(BadInput, NonFiniteRefusedOrDropped) {
  TempDir dir;
  const auto file = dir.write("nan.xyz", "1 2 3\n4 5 6\nnan 1 1\n7 8 inf\n9 9 9\n");
  expectInputError([&] { readPointCloud(file, defaults()); }, {"nan.xyz", "line 3", "NaN"});
  ReadOptions drop = defaults();
  drop.dropNonFinite = true;
  testing::internal::CaptureStderr();
  const PointCloud cloud = readPointCloud(file, drop);
  const std::string warning = testing::internal::GetCapturedStderr();
  EXPECT_EQ(cloud.splats.size(), 3u);
  EXPECT_NE(warning.find("dropped 2"), std::string::npos) << warning;
  EXPECT_NE(warning.find("line 3"), std::string::npos) << warning;

  // Binary PLY: the byte offset of the bad record.
  auto points = referencePoints(6);
  points[4].position[1] = std::numeric_limits<float>::quiet_NaN();
  const std::string ply = makePly(PlyFormat::Little, kXyz, points);
  const std::size_t header = ply.size() - 6 * 12;
  expectInputError([&] { readPointCloud(dir.write("nan.ply", ply), defaults()); },
                   {"nan.ply", "byte " + std::to_string(header + 4 * 12)});
  EXPECT_EQ(readPointCloud(dir.write("nan2.ply", ply), drop).splats.size(), 5u);

  // Only NaN: nothing left.
  expectInputError([&] { readPointCloud(dir.write("all.xyz", "nan 0 0\n"), drop); },
                   {"all.xyz", "NaN"});
  // NaN in a mesh vertex: refused, or its faces dropped (the square keeps one triangle).
  const std::string square = "3 4 0 1\n3 0 2 1\n";
  const std::string offText = "OFF\n5 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n-1 nan 0\n" + square;
  const std::string plyText =
      "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
      "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n1 1 0\n-1 nan 0\n" +
      square;
  expectInputError([&] { readPointCloud(dir.write("nanmesh.ply", plyText), defaults()); },
                   {"nanmesh.ply", "line 14"});
  testing::internal::CaptureStderr();
  for (const auto& [name, text] : {std::pair{"d.off", offText}, std::pair{"d.ply", plyText}}) {
    const PointCloud mesh = readPointCloud(dir.write(name, text), drop);
    ASSERT_EQ(mesh.splats.size(), 2000u) << name;
    for (const Splat& s : mesh.splats) ASSERT_LE(s.position[0] + s.position[1], 1.0f + 1e-6f);
  }
  EXPECT_NE(testing::internal::GetCapturedStderr().find("dropped 1 vertices"), std::string::npos);
  expectInputError(
      [&] {
        readPointCloud(dir.write("nan.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"),
                       defaults());
      },
      {"nan.off", "line 4"});
}

// Counts and numbers from a file are checked before any arithmetic or cast
// that could wrap or be undefined.
TEST(BadInput, CountsThatWouldWrapAndValuesBeyondFloatAreRefused) {
  TempDir dir;
  ReadOptions options = defaults();
  options.meshSamplePoints = 100;
  // n + 1 wraps to 0 for this count: the face must still be refused, by line.
  expectInputError(
      [&] {
        readPointCloud(dir.write("wrap.off",
                                 "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n"
                                 "18446744073709551615 0 1 2\n"),
                       options);
      },
      {"wrap.off", "line 6", "face 0"});
  // Beyond float range, yet finite as a double.
  expectInputError(
      [&] {
        readPointCloud(dir.write("big.off", "OFF\n3 1 0\n0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n"),
                       options);
      },
      {"big.off", "line 4", "float range"});
  // ASCII PLY list lengths and indices that no integer holds.
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n";
  expectInputError([&] { readPointCloud(dir.write("len.ply", header + "1e30 0 1 2\n"), options); },
                   {"len.ply", "line 13", "bad list length"});
  expectInputError([&] { readPointCloud(dir.write("nan.ply", header + "nan 0 1 2\n"), options); },
                   {"nan.ply", "line 13", "bad list length"});
  expectInputError(
      [&] { readPointCloud(dir.write("idx.ply", header + "3 0 1 1e300\n"), options); },
      {"idx.ply", "line 13", "face vertex index 1.0000000000000001e+300 out of range"});
}

TEST(BadInput, XyzLayouts) {
  TempDir dir;
  expectInputError(
      [&] { readPointCloud(dir.write("cols.xyz", "1 2 3\n4 5 6\n7 8\n"), defaults()); },
      {"cols.xyz", "line 3", "2 values"});
  expectInputError([&] { readPointCloud(dir.write("five.xyz", "1 2 3 4 5\n"), defaults()); },
                   {"five.xyz", "line 1", "5 values"});
  expectInputError([&] { readPointCloud(dir.write("word.xyz", "1 2 3\n1 two 3\n"), defaults()); },
                   {"word.xyz", "line 2", "not a number"});
  expectInputError([&] { readPointCloud(dir.write("count.pts", "5\n1 2 3\n4 5 6\n"), defaults()); },
                   {"count.pts", "line 3", "announces 5 points but the file has 2"});
  expectInputError([&] { readPointCloud(dir.write("amb.xyz", "0 0 0 -300 5 5\n"), defaults()); },
                   {"amb.xyz", "line 1", "normals from colours"});
}

// Past the sniffed lines XYZ is parsed in parallel blocks: the same points in
// the same order, and the first bad line reported as line-by-line reading
// would (a NaN before a word is the NaN's error).
TEST(XyzReader, LongFilesReadInBlocksAsLineByLine) {
  TempDir dir;
  std::string text = "# a scan\n";
  for (int i = 0; i < 70000; ++i) {
    text += std::to_string(i % 97) + " " + std::to_string(i % 89) + ".5 " + std::to_string(i) +
            " 10 20 30\n";
    if (i % 5000 == 0) text += "\n# comment\n";
  }
  const auto cloud = readPointCloud(dir.write("long.xyz", text), defaults());
  ASSERT_EQ(cloud.splats.size(), 70000u);
  EXPECT_TRUE(cloud.hasColors);
  for (int i = 0; i < 70000; i += 6999) {
    EXPECT_EQ(cloud.splats[static_cast<std::size_t>(i)].position[2], static_cast<float>(i));
    EXPECT_EQ(cloud.splats[static_cast<std::size_t>(i)].color[1], 20);
  }
  std::string bad;
  for (int i = 1; i <= 50000; ++i) {
    if (i == 41000)
      bad += "1 two 3\n";
    else if (i == 40000)
      bad += "1 nan 3\n";
    else if (i == 45000)
      bad += "1 2\n";
    else
      bad += "1 2 3\n";
  }
  expectInputError([&] { readPointCloud(dir.write("nan.xyz", bad), defaults()); },
                   {"nan.xyz", "line 40000", "non-finite"});
  ReadOptions drop = defaults();
  drop.dropNonFinite = true;
  expectInputError([&] { readPointCloud(dir.write("word.xyz", bad), drop); },
                   {"word.xyz", "line 41000", "not a number: 'two'"});
}

// Blocks of 8 MiB are read whole and cut into pieces at line ends: lines that
// straddle a block or a piece, CRLF ends, comments, blank lines and a last
// line without its end all read as line by line, and a bad line in a later
// block is named by its number in the file.
TEST(XyzReader, LinesAcrossBlocksAndPiecesKeepTheirNumbers) {
  TempDir dir;
  constexpr int kLines = 500'000;  // about 17 MiB: three blocks
  std::string text;
  for (int i = 0; i < kLines; ++i) {
    text += std::to_string(i) + ".25 -" + std::to_string(i % 1000) + " 7e-3 1 2 3";
    text += (i % 3 == 0) ? "\r\n" : "\n";
    if (i % 40'000 == 0) text += "\n   \n# a comment\n";
  }
  text += "1 2 3 4 5 6";  // no end of line
  const auto cloud = readPointCloud(dir.write("blocks.xyz", text), defaults());
  ASSERT_EQ(cloud.splats.size(), static_cast<std::size_t>(kLines) + 1);
  for (int i = 0; i < kLines; i += 12'347) {
    const Splat& s = cloud.splats[static_cast<std::size_t>(i)];
    EXPECT_EQ(s.position[0], static_cast<float>(i + 0.25)) << i;
    EXPECT_EQ(s.position[1], -static_cast<float>(i % 1000)) << i;
    EXPECT_EQ(s.position[2], 7e-3f) << i;
  }
  EXPECT_EQ(cloud.splats.back().position[0], 1.0f);
  EXPECT_EQ(cloud.splats.back().color[2], 6);

  // The file's line of point j: one line each, and three more after every
  // 40,000th point.
  const auto lineOf = [](int j) { return j + 1 + 3 * (j / 40'000 + 1); };
  std::string bad = text;
  const std::string wanted = "450000.25 -0 7e-3 1 2 3";
  const std::size_t at = bad.find(wanted);
  ASSERT_NE(at, std::string::npos);
  bad.replace(at, wanted.size(), "450000.25 oops 7e-3 1 2 3");
  expectInputError([&] { readPointCloud(dir.write("bad.xyz", bad), defaults()); },
                   {"bad.xyz", "line " + std::to_string(lineOf(450'000)), "not a number: 'oops'"});
}

// Mapped blocks hold the lines FileReader's blocks hold, from any offset and
// for any size asked: whole lines of at least that many bytes where the file
// has them (the last may lack its end), a line longer than the block in a
// larger window, then nothing.
TEST(MappedLineBlocks, WholeLinesOfTheFileInOrder) {
  using pointillist::preprocess::detail::FileReader;
  using pointillist::preprocess::detail::MappedLineBlocks;
  TempDir dir;
  std::string text = "# header\n";
  for (int i = 0; i < 30'000; ++i) {
    text += std::to_string(i) + " " + std::to_string(i * 7 % 1000) + ".5 3\n";
    if (i == 12'345) text += std::string(200'000, '1') + "\n";  // longer than most blocks
  }
  text += "9 9 9";  // no end of line
  const fs::path file = dir.write("blocks.xyz", text);
  for (const std::size_t want : {std::size_t{1}, std::size_t{4096}, std::size_t{65'536},
                                 std::size_t{1} << 20, std::size_t{64} << 20}) {
    FileReader buffered(file);
    std::string_view header;
    ASSERT_TRUE(buffered.readLine(header));
    const auto mapped = MappedLineBlocks::open(file, buffered.offset());
    ASSERT_NE(mapped, nullptr);
    EXPECT_EQ(mapped->size(), text.size());
    std::string joined(header);
    joined += '\n';
    std::size_t blocks = 0;
    for (std::string_view block; !(block = mapped->next(want, 0)).empty(); ++blocks) {
      joined += block;
      EXPECT_EQ(mapped->offset(), joined.size());
      if (joined.size() < text.size()) {
        EXPECT_EQ(block.back(), '\n') << "block " << blocks << " of " << want << " bytes";
        EXPECT_GE(block.size(), std::min(want, text.size() - (joined.size() - block.size())));
      }
    }
    EXPECT_EQ(joined, text) << want;
    EXPECT_TRUE(mapped->next(want, 0).empty());
    // FileReader's blocks of the same file hold the same bytes.
    std::string viaBuffer(header);
    viaBuffer += '\n';
    for (std::string_view block; !(block = buffered.readLineBlock(want)).empty();)
      viaBuffer += block;
    EXPECT_EQ(viaBuffer, joined);
  }
}

// A pipe cannot be mapped (the XYZ reader then reads it through the buffer,
// to the same points); a file cut short between blocks is refused, not
// faulted on.
TEST(MappedLineBlocks, PipesFallBackAndShrunkFilesAreRefused) {
  using pointillist::preprocess::detail::MappedLineBlocks;
  TempDir dir;
  std::string text;
  for (int i = 0; i < 200'000; ++i)
    text += std::to_string(i) + " -2.25 " + std::to_string(i % 13) + "\n";
  const fs::path file = dir.write("points.xyz", text);
  const fs::path fifo = dir.path() / "pipe.xyz";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(MappedLineBlocks::open(dir.path(), 0), nullptr);
  std::thread writer([&] {
    std::ofstream out(fifo, std::ios::binary);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
  });
  pointillist::preprocess::PointCloud fromPipe;
  try {
    fromPipe = readPointCloud(fifo, defaults());
  } catch (...) {
    // Let the writer finish (it waits for a reader) before failing.
    std::ifstream drain(fifo, std::ios::binary);
    drain.ignore(std::numeric_limits<std::streamsize>::max());
    writer.join();
    throw;
  }
  writer.join();
  const auto fromFile = readPointCloud(file, defaults());
  ASSERT_EQ(fromPipe.splats.size(), 200'000u);
  ASSERT_EQ(fromFile.splats.size(), fromPipe.splats.size());
  EXPECT_EQ(std::memcmp(fromFile.splats.data(), fromPipe.splats.data(),
                        fromFile.splats.size() * sizeof(Splat)),
            0);

  const auto mapped = MappedLineBlocks::open(file, 0);
  ASSERT_NE(mapped, nullptr);
  EXPECT_FALSE(mapped->next(4096, 0).empty());
  fs::resize_file(file, text.size() / 2);
  expectInputError([&] { mapped->next(4096, 0); }, {"points.xyz", "shrank"});

  // A "line" past the limit FileReader sets (64 MiB) is not text.
  const fs::path binary = dir.write("binary.xyz", "1 2 3\n" + std::string((65u << 20) + 10, '7'));
  const auto huge = MappedLineBlocks::open(binary, 0);
  ASSERT_NE(huge, nullptr);
  EXPECT_EQ(huge->next(1, 0), "1 2 3\n");
  expectInputError([&] { huge->next(4096, 1); }, {"binary.xyz", "line 2", "line too long"});
}

// The XYZ blocks parse a line in one pass (parseNumbers) and fall back to
// splitting it: whenever the one pass accepts a line, splitting gives the
// same count and bit for bit the same values; lines it refuses are ones the
// split way refuses too, or has a message for.
TEST(XyzReader, OnePassParsingAgreesWithSplitting) {
  using namespace pointillist::preprocess::detail;
  const std::vector<std::string> lines = {
      "1 2 3",     "+1 2 3",   "1,2,3",     "1 2 3 ",   "\t1\t2\t3\r", "  -0.5e3 7 8", "1 2",
      "1 2 3 4",   "1e5x 2 3", "+ 1 2",     "++1 2 3",  "nan 1 2",     "inf -inf 0",   "",
      "   ",       "1 2 3#",   "0x10 1 2",  "1. .5 5.", "1 2 3,",      ",1 2 3",       "1 2 +",
      "1e400 1 2", "1 - 2",    "1.5.5 2 3", "3 4 5\v"};
  for (const std::string& line : lines) {
    double fast[3] = {0, 0, 0};
    const bool accepted = parseNumbers(line, fast, 3);
    std::vector<std::string_view> fields;
    splitFields(line, fields);
    bool split = fields.size() == 3;
    double slow[3] = {0, 0, 0};
    for (std::size_t i = 0; split && i < 3; ++i) split = parseDouble(fields[i], slow[i]);
    EXPECT_EQ(accepted, split) << "'" << line << "'";
    if (accepted && split) {
      for (int i = 0; i < 3; ++i) {
        EXPECT_EQ(std::bit_cast<std::uint64_t>(fast[i]), std::bit_cast<std::uint64_t>(slow[i]))
            << "'" << line << "' value " << i;
      }
    }
  }
}

// parseNumbers reads plain decimals without std::from_chars where the
// conversion is exact (Clinger's fast path): wherever it takes a number, it
// must give from_chars' bits and end where from_chars ends.
TEST(XyzReader, ShortDecimalsParseAsFromCharsDoes) {
  using pointillist::preprocess::detail::parseShortDecimal;
  std::mt19937_64 rng(7);
  const auto digits = [&](int n) {
    std::string d;
    for (int i = 0; i < n; ++i) d += static_cast<char>('0' + rng() % 10);
    return d;
  };
  std::vector<std::string> numbers = {"0",
                                      "-0",
                                      "0.0",
                                      "-0.0",
                                      "1",
                                      "9007199254740992",
                                      "9007199254740993",
                                      "1e22",
                                      "1e23",
                                      "1e-22",
                                      "1e-23",
                                      "123456789012345678",
                                      "1234567890123456789",
                                      "12345678901234567890",
                                      "0.1",
                                      "0.3",
                                      "5.",
                                      ".5",
                                      "1e",
                                      "1e+",
                                      "1E+5",
                                      "1e-5x",
                                      "-",
                                      "--1",
                                      "inf",
                                      "nan",
                                      "1.5.5",
                                      "0x10",
                                      "4.35",
                                      "0.25065574",
                                      "-0.43347988",
                                      "128"};
  for (int i = 0; i < 2'000'000; ++i) {
    std::string n = (rng() % 2 != 0) ? "-" : "";
    n += digits(1 + static_cast<int>(rng() % 12));
    // Appended piece by piece: GCC 12 at -O3 warns (-Wrestrict, a false
    // positive) on a string literal + std::string here.
    if (rng() % 4 != 0) {
      n += '.';
      n += digits(1 + static_cast<int>(rng() % 12));
    }
    if (rng() % 5 == 0) {
      n += (rng() % 2 != 0) ? 'e' : 'E';
      const int e = static_cast<int>(rng() % 61) - 30;
      if (e < 0) {
        n += '-';
      } else if (rng() % 2 != 0) {
        n += '+';
      }
      n += std::to_string(std::abs(e));
    }
    numbers.push_back(n);
  }
  std::size_t fast = 0;
  for (const std::string& n : numbers) {
    const char* end = n.data() + n.size();
    double value = 0.0, expected = 0.0;
    const char* stop = parseShortDecimal(n.data(), end, value);
    if (stop == nullptr) continue;
    ++fast;
    const auto result = std::from_chars(n.data(), end, expected);
    ASSERT_EQ(result.ec, std::errc()) << n;
    EXPECT_EQ(stop, result.ptr) << n;
    EXPECT_EQ(std::bit_cast<std::uint64_t>(value), std::bit_cast<std::uint64_t>(expected)) << n;
    // In a block the line goes on after the number: it must end in the same
    // place and give the same bits.
    std::string followed = n;
    followed += " 7 8\n-0.5";
    double again = 0.0;
    const char* stopAgain =
        parseShortDecimal(followed.data(), followed.data() + followed.size(), again);
    ASSERT_NE(stopAgain, nullptr) << n;
    EXPECT_EQ(stopAgain - followed.data(), stop - n.data()) << n;
    EXPECT_EQ(std::bit_cast<std::uint64_t>(again), std::bit_cast<std::uint64_t>(value)) << n;
  }
  // Every run of 1 to 25 digits, after and before a point, with text after.
  std::size_t shortTaken = 0;
  for (int whole = 1; whole <= 25; ++whole) {
    for (int fraction = 0; fraction <= 25; ++fraction) {
      std::string n = digits(whole);
      if (fraction > 0) {
        n += '.';
        n += digits(fraction);
      }
      std::string followed = n;
      followed += "x1234567";
      double value = 0.0, expected = 0.0;
      const char* stop =
          parseShortDecimal(followed.data(), followed.data() + followed.size(), value);
      if (stop == nullptr) continue;
      ++shortTaken;
      const auto result =
          std::from_chars(followed.data(), followed.data() + followed.size(), expected);
      EXPECT_EQ(stop, result.ptr) << n;
      EXPECT_EQ(std::bit_cast<std::uint64_t>(value), std::bit_cast<std::uint64_t>(expected)) << n;
    }
  }
  // Those of up to 15 digits in all (120 of the 650) always fit the fast path.
  EXPECT_GE(shortTaken, 120u);
  // With 64 bytes after it a number is read 8 digits at a time: the same
  // answer (refused, or the same end and bits) as a byte at a time, for
  // each random number and each digit run, whatever follows (a blank, a
  // point, a digit-like byte, bytes above 0xF9 whose carry a SWAR test must
  // not let through).
  const std::string tails[] = {" 7 8\n", "x", ".", ":", "/", "\xFA\xFF", "\n", "e5 ", "E-3"};
  std::size_t swarTaken = 0;
  for (std::size_t i = 0; i < numbers.size(); ++i) {
    std::string padded = numbers[i];
    padded += tails[i % std::size(tails)];
    padded.append(80, '9');
    const char* end = padded.data() + padded.size();
    double bytes = 0.0, swar = 0.0;
    const char* stopBytes =
        pointillist::preprocess::detail::parseShortDecimalBytes(padded.data(), end, bytes);
    const char* stopSwar = parseShortDecimal(padded.data(), end, swar);
    ASSERT_EQ(stopSwar, stopBytes) << padded;
    if (stopSwar == nullptr) continue;
    ++swarTaken;
    EXPECT_EQ(std::bit_cast<std::uint64_t>(swar), std::bit_cast<std::uint64_t>(bytes)) << padded;
  }
  EXPECT_GT(swarTaken, numbers.size() / 2);
  // Most of them take the fast path (the rest have a wide exponent or too
  // many digits), as scanner exports do.
  EXPECT_GT(fast, numbers.size() / 2);
}

// A plain line is read in one pass to its end (parsePlainLine): wherever it
// takes a line, parseNumbers takes the same line with the same bits, and the
// next line starts where it says.
TEST(XyzReader, PlainLinesParseAsParseNumbersDoes) {
  using namespace pointillist::preprocess::detail;
  const std::vector<std::string> lines = {"0.25065574 -0.43347988 -0.07969354",
                                          "1 2 3",
                                          "+1 2 3",
                                          "1,2,3",
                                          "1 2 3 ",
                                          "\t1\t2\t3\r",
                                          "  -0.5e3 7 8",
                                          "1 2",
                                          "1 2 3 4",
                                          "1e5x 2 3",
                                          "nan 1 2",
                                          "",
                                          "   ",
                                          "1 2 3#",
                                          "1 2 3 # a comment",
                                          "1. .5 5.",
                                          "1 2 3,",
                                          "1 2 +",
                                          "1 - 2",
                                          "1.5.5 2 3",
                                          "3 4 5\v",
                                          "12345678901234567890 1 2",
                                          "1234567890123456789 1 2",
                                          "0.123456789012345678 1 2",
                                          "-0.081036836 128 128"};
  std::size_t taken = 0;
  for (const std::string& line : lines) {
    for (const std::string& after : {std::string("\n"), std::string("\r\n"), std::string()}) {
      std::string block = line + after;
      const std::size_t lineEnd = block.size();
      if (!after.empty()) block.append(100, '7');  // the next line
      double plain[3] = {0, 0, 0}, numbers[3] = {0, 0, 0};
      const char* next = parsePlainLine(block.data(), block.data() + block.size(), plain, 3);
      if (next == nullptr) continue;
      ++taken;
      EXPECT_EQ(next - block.data(), static_cast<std::ptrdiff_t>(lineEnd)) << "'" << line << "'";
      std::string_view text(block.data(), lineEnd);
      if (!text.empty() && text.back() == '\n') text.remove_suffix(1);
      if (!text.empty() && text.back() == '\r') text.remove_suffix(1);
      ASSERT_TRUE(parseNumbers(text, numbers, 3)) << "'" << line << "'";
      for (int i = 0; i < 3; ++i)
        EXPECT_EQ(std::bit_cast<std::uint64_t>(plain[i]), std::bit_cast<std::uint64_t>(numbers[i]))
            << "'" << line << "' value " << i;
    }
  }
  // The plain ones with a line after them (the last line of a block has too
  // few bytes after it to be read 8 at a time, and goes the other way).
  EXPECT_GE(taken, 16u);
}

TEST(PlyReader, LongBinaryBodiesReadInBlocksAsRecordByRecord) {
  // Records go in blocks of 65536, the next read while one is decoded: more
  // than two blocks, whole, cut short in the third, and with a NaN in the second.
  TempDir dir;
  const std::vector<PlyProperty> properties = {{"float", "x"},     {"float", "y"},
                                               {"float", "z"},     {"uchar", "red"},
                                               {"uchar", "green"}, {"uchar", "blue"}};
  std::vector<Splat> points(150000);
  for (std::size_t i = 0; i < points.size(); ++i) {
    Splat& s = points[i];
    s.position[0] = static_cast<float>(i % 1013);
    s.position[1] = static_cast<float>(i) * 0.25f;
    s.position[2] = -static_cast<float>(i % 37);
    for (int c = 0; c < 3; ++c)
      s.color[c] = static_cast<std::uint8_t>((i + 50u * static_cast<unsigned>(c)) % 256u);
    s.color[3] = 255;
  }
  const std::string binary = makePly(PlyFormat::Little, properties, points);
  const auto cloud = readPointCloud(dir.write("long.ply", binary), defaults());
  expectSamePoints(cloud, points, false, true, false, false);

  constexpr std::size_t kRecord = 15;
  const std::size_t header = binary.size() - points.size() * kRecord;
  const std::string cut = binary.substr(0, header + 140000 * kRecord + 7);
  expectInputError([&] { readPointCloud(dir.write("cut.ply", cut), defaults()); },
                   {"cut.ply", "byte " + std::to_string(header + 140000 * kRecord),
                    "truncated vertex data (expected 150000 vertices, got 140000)"});

  std::string nan = binary;
  const float notANumber = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(nan.data() + header + 70000 * kRecord + 4, &notANumber, sizeof notANumber);
  expectInputError([&] { readPointCloud(dir.write("nan.ply", nan), defaults()); },
                   {"nan.ply", "byte " + std::to_string(header + 70000 * kRecord), "non-finite"});
  ReadOptions drop = defaults();
  drop.dropNonFinite = true;
  const auto dropped = readPointCloud(dir.write("nan.ply", nan), drop);
  ASSERT_EQ(dropped.splats.size(), points.size() - 1);
  EXPECT_EQ(dropped.splats[69999].position[1], points[69999].position[1]);
  EXPECT_EQ(dropped.splats[70000].position[1], points[70001].position[1]);
}

TEST(BadInput, Meshes) {
  TempDir dir;
  const auto bad = [&](const std::string& name, const std::string& text,
                       const std::vector<std::string>& needles) {
    expectInputError([&] { readPointCloud(dir.write(name, text), defaults()); }, needles);
  };
  bad("kw.off", "OFX\n3 1 0\n", {"kw.off", "line 1", "not an OFF"});
  bad("counts.off", "OFF\n# c\nthree 1 0\n", {"counts.off", "line 3", "counts"});
  bad("verts.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n",
      {"verts.off", "line 4", "expected 3 vertices, got 2"});
  bad("faces.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
      {"faces.off", "line 6", "expected 2 faces, got 1"});
  bad("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
      {"range.off", "line 6", "index 3 out of range"});
  bad("short.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", {"short.off", "line 6"});
  bad("flat.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n", {"flat.off", "degenerate"});
  bad("absurd.off", "OFF\n99999999 1 0\n0 0 0\n", {"absurd.off", "line 2", "absurd"});
  // PLY faces: index out of range (ascii: line, binary: byte).
  const std::string head =
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  bad("range.ply", "ply\nformat ascii 1.0\n" + head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
      {"range.ply", "line 13", "index 7 out of range"});
  std::string binary = "ply\nformat binary_little_endian 1.0\n" + head;
  const std::size_t faceAt = binary.size() + 3 * 12;
  binary += std::string(3 * 12, '\0');
  binary += std::string("\x03\x00\x00\x00\x00\x01\x00\x00\x00\x09\x00\x00\x00", 13);
  bad("range_bin.ply", binary, {"range_bin.ply", "byte " + std::to_string(faceAt), "out of range"});
  bad("flat.ply", "ply\nformat ascii 1.0\n" + head + "0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n",
      {"flat.ply", "degenerate"});
}

// Blocks are decoded into the cloud and checked for normals on all threads:
// the cloud has normals only when every record has one, read whole or
// streamed, wherever the record without one lies.
TEST(PlyReader, NormalsFlagHoldsOnlyWhenEveryRecordOfEveryBlockHasOne) {
  TempDir dir;
  const std::vector<PlyProperty> properties = {{"float", "x"},  {"float", "y"},  {"float", "z"},
                                               {"float", "nx"}, {"float", "ny"}, {"float", "nz"}};
  std::vector<Splat> points(140000);
  for (std::size_t i = 0; i < points.size(); ++i) {
    Splat& s = points[i];
    s.position[0] = static_cast<float>(i % 977);
    s.position[1] = static_cast<float>(i) * 0.5f;
    s.position[2] = 1.0f;
    s.normal[i % 3] = (i % 2) != 0u ? 1.0f : -1.0f;
  }
  const auto read = [&](const std::vector<Splat>& records, const std::string& name) {
    const auto file = dir.write(name, makePly(PlyFormat::Little, properties, records));
    PointCloud whole = readPointCloud(file, defaults());
    const Streamed streamed = readStreamed(file, 30000);
    EXPECT_EQ(streamed.flags.hasNormals, whole.hasNormals) << name;
    EXPECT_EQ(streamed.splats.size(), whole.splats.size()) << name;
    EXPECT_EQ(std::memcmp(streamed.splats.data(), whole.splats.data(),
                          streamed.splats.size() * sizeof(Splat)),
              0)
        << name;
    return whole;
  };
  expectSamePoints(read(points, "all.ply"), points, true, false, false, false);
  // One record without a normal: in the first block, in the last (short) one.
  for (const std::size_t without : {std::size_t{17}, std::size_t{139999}}) {
    std::vector<Splat> some = points;
    for (float& n : some[without].normal) n = 0.0f;
    const PointCloud cloud = read(some, "some" + std::to_string(without) + ".ply");
    EXPECT_FALSE(cloud.hasNormals) << without;
    ASSERT_EQ(cloud.splats.size(), some.size());
    for (std::size_t i = 0; i < some.size(); ++i) {
      ASSERT_EQ(cloud.splats[i].position[1], some[i].position[1]) << i;
      ASSERT_EQ(cloud.splats[i].normal[i % 3], some[i].normal[i % 3]) << i;
    }
  }
}
