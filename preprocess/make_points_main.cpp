// pointillist-make-points: writes benchmark and test inputs as users bring
// them -- a binary PLY point cloud or an XYZ text scan -- from a sampled mesh
// or a generated scene, in blocks, so that inputs far bigger than memory can
// be made (a 200 M-point file needs only one block in memory).
#include <CLI/CLI.hpp>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "common/errors.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/mesh_sampler.hpp"

namespace pp = pointillist::preprocess;
using pointillist::Splat;

namespace {

constexpr const char* kTool = "pointillist-make-points";

struct Options {
  std::string mesh;
  std::string generate;
  std::uint64_t points = 10'000'000;
  std::uint64_t blockPoints = 10'000'000;
  std::string format = "ply";
  bool normals = true;
  bool colors = true;
  std::uint64_t seed = 1;
  std::string output;
};

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

void writeAll(std::FILE* f, const void* data, std::size_t bytes, const std::string& path) {
  if (std::fwrite(data, 1, bytes, f) != bytes)
    throw pointillist::InputError(path + ": write failed (disk full?)");
}

void writePlyHeader(std::FILE* f, const Options& o) {
  std::string header = "ply\nformat binary_little_endian 1.0\ncomment made by " +
                       std::string(kTool) + "\nelement vertex " + std::to_string(o.points) +
                       "\nproperty float x\nproperty float y\nproperty float z\n";
  if (o.normals) header += "property float nx\nproperty float ny\nproperty float nz\n";
  if (o.colors) header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header += "end_header\n";
  writeAll(f, header.data(), header.size(), o.output);
}

// One record per splat, the layout the header declares.
void writePlyBlock(std::FILE* f, const std::vector<Splat>& splats, const Options& o) {
  const std::size_t record = std::size_t{12} + (o.normals ? 12u : 0u) + (o.colors ? 3u : 0u);
  std::vector<unsigned char> buffer(splats.size() * record);
  unsigned char* at = buffer.data();
  for (const Splat& s : splats) {
    std::memcpy(at, s.position, 12);
    at += 12;
    if (o.normals) {
      std::memcpy(at, s.normal, 12);
      at += 12;
    }
    if (o.colors) {
      std::memcpy(at, s.color, 3);
      at += 3;
    }
  }
  writeAll(f, buffer.data(), buffer.size(), o.output);
}

// "x y z[ nx ny nz][ r g b]" per line, shortest round-trip float text.
void writeXyzBlock(std::FILE* f, const std::vector<Splat>& splats, const Options& o) {
  std::string text;
  text.reserve(splats.size() * 64);
  char number[32];
  const auto put = [&](auto value) {
    const auto result = std::to_chars(number, number + sizeof number, value);
    text.append(number, result.ptr);
  };
  for (const Splat& s : splats) {
    put(s.position[0]);
    for (int a = 1; a < 3; ++a) text += ' ', put(s.position[a]);
    if (o.normals)
      for (float n : s.normal) text += ' ', put(n);
    if (o.colors)
      for (int c = 0; c < 3; ++c) text += ' ', put(static_cast<unsigned>(s.color[c]));
    text += '\n';
  }
  writeAll(f, text.data(), text.size(), o.output);
}

int run(const Options& o) {
  if (o.mesh.empty() == o.generate.empty())
    throw pointillist::UsageError("give exactly one of --mesh FILE and --generate NAME");
  if (o.points == 0 || o.blockPoints == 0)
    throw pointillist::UsageError("--points and --block-points must be positive");
  if (o.format != "ply" && o.format != "xyz")
    throw pointillist::UsageError("--format is ply or xyz, not '" + o.format + "'");
  if (o.output.empty()) throw pointillist::UsageError("-o/--output is required");

  pp::TriangleMesh mesh;
  if (!o.mesh.empty()) {
    pp::ReadOptions ro;
    mesh = pp::readOffMesh(o.mesh, ro);
  }
  const std::string partial = o.output + ".partial";
  File file(std::fopen(partial.c_str(), "wb"));
  if (!file) throw pointillist::InputError(partial + ": cannot create the file");
  // A failed run leaves no half-written file behind.
  class RemoveUnlessDone {
   public:
    explicit RemoveUnlessDone(std::string path) : path_(std::move(path)) {}
    ~RemoveUnlessDone() {
      std::error_code ignored;
      if (!done_) std::filesystem::remove(path_, ignored);
    }
    void done() { done_ = true; }

   private:
    std::string path_;
    bool done_ = false;
  } cleanup(partial);
  if (o.format == "ply") writePlyHeader(file.get(), o);
  std::uint64_t written = 0;
  for (std::uint64_t block = 0; written < o.points; ++block) {
    const std::uint64_t count = std::min(o.blockPoints, o.points - written);
    // A new seed per block: more blocks give a denser sampling of the same scene.
    const pp::PointCloud cloud = o.mesh.empty()
                                     ? pp::generateScene(o.generate, count, o.seed + block)
                                     : pp::sampleMesh(mesh, count, o.seed + block, o.mesh);
    if (o.format == "ply")
      writePlyBlock(file.get(), cloud.splats, o);
    else
      writeXyzBlock(file.get(), cloud.splats, o);
    written += count;
    std::fprintf(stderr, "\r%s: %llu / %llu points", kTool,
                 static_cast<unsigned long long>(written),
                 static_cast<unsigned long long>(o.points));
  }
  if (std::fclose(file.release()) != 0) throw pointillist::InputError(partial + ": write failed");
  std::filesystem::rename(partial, o.output);
  cleanup.done();
  std::fprintf(stderr, "\n%s: wrote %s (%llu points, %.1f MiB)\n", kTool, o.output.c_str(),
               static_cast<unsigned long long>(o.points),
               static_cast<double>(std::filesystem::file_size(o.output)) / (1024.0 * 1024.0));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Writes a point-cloud input file (binary PLY or XYZ text) from a sampled mesh or a "
      "generated scene, in blocks, for benchmarks and tests of pointillist-preprocess.",
      kTool};
  Options o;
  app.add_option("--mesh", o.mesh, "OFF mesh to sample");
  app.add_option("--generate", o.generate, "Generated scene instead (city, sphere, torus)");
  app.add_option("--points", o.points, "Points to write")->capture_default_str();
  app.add_option("--block-points", o.blockPoints,
                 "Points made and written at a time (each block a new seed)")
      ->capture_default_str();
  app.add_option("--format", o.format, "ply (binary little-endian) or xyz (text)")
      ->capture_default_str();
  app.add_flag("!--no-normals", o.normals, "Leave the normals out");
  app.add_flag("!--no-colors", o.colors, "Leave the colours out");
  app.add_option("--seed", o.seed, "Seed of the first block")->capture_default_str();
  app.add_option("-o,--output", o.output, "File to write (replaced)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: error: %s\n", kTool, e.what());
    return 1;
  }
}
