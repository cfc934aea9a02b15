#include "preprocess/readers.hpp"

#include <algorithm>
#include <cctype>
#include <string>
#include <system_error>
#include <utility>

#include "common/errors.hpp"
#include "preprocess/las_reader.hpp"
#include "preprocess/mesh_sampler.hpp"
#include "preprocess/ply_reader.hpp"
#include "preprocess/reader_toolkit.hpp"
#include "preprocess/xyz_reader.hpp"

namespace pointillist::preprocess {
namespace {

std::string lowerExtension(const std::filesystem::path& file) {
  std::string ext = file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

// Each file's size (0 when unknown) and their sum: progress over several
// files is counted in bytes.
std::vector<std::uint64_t> fileSizes(const std::vector<std::filesystem::path>& files,
                                     std::uint64_t& total) {
  std::vector<std::uint64_t> sizes;
  total = 0;
  for (const auto& f : files) {
    std::error_code ec;
    const std::uint64_t size = std::filesystem::file_size(f, ec);
    sizes.push_back(ec ? 0 : size);
    total += sizes.back();
  }
  return sizes;
}

}  // namespace

PointCloud readPointCloud(const std::filesystem::path& file, const ReadOptions& options) {
  const std::string ext = lowerExtension(file);
  if (ext == ".ply") return readPly(file, options);
  if (ext == ".xyz" || ext == ".pts" || ext == ".txt") return readXyz(file, options);
  if (ext == ".las") return readLas(file, options);
  if (ext == ".off") return readOff(file, options);
  if (ext == ".laz") {
    detail::failFile(file,
                     "LAZ (compressed LAS) is not supported; decompress it first, e.g. "
                     "`laszip -i in.laz -o out.las`");
  }
  detail::failFile(
      file, "unknown file type '" + ext + "' (expected .ply, .xyz, .pts, .txt, .las or .off)");
}

PointCloud readPointClouds(const std::vector<std::filesystem::path>& files,
                           const ReadOptions& options) {
  if (files.empty()) throw UsageError("no input files given");
  if (files.size() == 1) return readPointCloud(files.front(), options);

  std::uint64_t total = 0;
  const std::vector<std::uint64_t> sizes = fileSizes(files, total);

  PointCloud merged;
  merged.hasNormals = merged.hasColors = merged.hasRadii = true;
  std::uint64_t base = 0;
  for (std::size_t i = 0; i < files.size(); ++i) {
    ReadOptions one = options;
    if (options.progress) {
      const std::uint64_t size = sizes[i];
      one.progress = [&options, base, size, total](std::uint64_t done, std::uint64_t) {
        options.progress(base + std::min(done, size), total);
      };
    }
    PointCloud cloud = readPointCloud(files[i], one);
    base += sizes[i];
    merged.hasNormals = merged.hasNormals && cloud.hasNormals;
    merged.hasColors = merged.hasColors && cloud.hasColors;
    merged.hasRadii = merged.hasRadii && cloud.hasRadii;
    merged.source += (i == 0 ? "" : ", ") + cloud.source;
    if (merged.splats.empty()) {
      merged.splats = std::move(cloud.splats);
    } else {
      merged.splats.insert(merged.splats.end(), cloud.splats.begin(), cloud.splats.end());
    }
  }
  return merged;
}

PointCloud streamPointClouds(const std::vector<std::filesystem::path>& files,
                             const ReadOptions& options,
                             const std::function<void(std::span<const Splat>)>& sink,
                             std::uint64_t& count) {
  if (files.empty()) throw UsageError("no input files given");
  std::uint64_t total = 0;
  const std::vector<std::uint64_t> sizes = fileSizes(files, total);
  count = 0;
  PointCloud merged;
  merged.hasNormals = merged.hasColors = merged.hasRadii = true;
  std::uint64_t base = 0;
  for (std::size_t i = 0; i < files.size(); ++i) {
    ReadOptions one = options;
    one.sink = [&](std::span<const Splat> block) {
      count += block.size();
      sink(block);
    };
    if (options.progress) {
      const std::uint64_t size = sizes[i];
      one.progress = [&options, base, size, total](std::uint64_t done, std::uint64_t) {
        options.progress(base + std::min(done, size), total);
      };
    }
    PointCloud cloud = readPointCloud(files[i], one);
    // Meshes come back whole (their samples).
    const std::span<const Splat> held(cloud.splats);
    for (std::size_t at = 0; at < held.size(); at += options.sinkBlock)
      one.sink(held.subspan(at, std::min(options.sinkBlock, held.size() - at)));
    base += sizes[i];
    merged.hasNormals = merged.hasNormals && cloud.hasNormals;
    merged.hasColors = merged.hasColors && cloud.hasColors;
    merged.hasRadii = merged.hasRadii && cloud.hasRadii;
    merged.source += (i == 0 ? "" : ", ") + cloud.source;
  }
  return merged;
}

}  // namespace pointillist::preprocess
