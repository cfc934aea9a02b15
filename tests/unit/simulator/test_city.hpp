#pragma once
// What the simulator's tests build their scenes from: a small generated city
// preprocessed in memory, and a temporary directory for what goes to disk.
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>

#include "common/dataset_writer.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"

namespace pointillist::simulator::fixtures {

// The built-in city of `points` points (generator seed `seed`), `leafPoints`
// a leaf, top-level cells at `topLevelDepth`, finalized.
inline DatasetContent smallCityContent(std::size_t points, std::uint64_t seed,
                                       std::uint32_t leafPoints = 64, int topLevelDepth = 3) {
  auto cloud = preprocess::generateScene("city", points, seed);
  preprocess::PreprocessOptions options;
  options.octree.leafPoints = leafPoints;
  options.topLevelDepth = topLevelDepth;
  options.threads = 1;
  DatasetContent content = preprocess::buildDatasetContent(std::move(cloud.splats), options);
  finalizeDatasetContent(content);
  return content;
}

// A directory under the system's temporary one, named for the test and the
// process, empty at the start and removed at the end.
class TempDir {
 public:
  explicit TempDir(const std::string& name = "simulator-test") {
    path_ = std::filesystem::temp_directory_path() /
            ("pointillist-" + name + "-" + std::to_string(::getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace pointillist::simulator::fixtures
