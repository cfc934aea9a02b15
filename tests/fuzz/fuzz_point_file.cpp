// libFuzzer target: one point or mesh file reader of pointillist-preprocess,
// chosen at build time (POINTILLIST_FUZZ_EXTENSION: ".ply", ".xyz", ".las",
// ".off"). The readers take paths, so each input is written to a file in
// /dev/shm first. A reader may refuse an input (InputError, the clear
// message users get); anything else (a crash, a hang, a sanitizer report, another
// exception) is a finding.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "common/errors.hpp"
#include "preprocess/readers.hpp"

namespace {

std::filesystem::path inputPath() {
  const char* shm = "/dev/shm";
  const std::filesystem::path dir = std::filesystem::exists(shm)
                                        ? std::filesystem::path(shm)
                                        : std::filesystem::temp_directory_path();
  return dir / ("pointillist-fuzz-" + std::to_string(::getpid()) + POINTILLIST_FUZZ_EXTENSION);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path path = inputPath();
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  pointillist::preprocess::ReadOptions options;
  options.meshSamplePoints = 2000;  // meshes: sampled, kept small per input
  options.dropNonFinite = (size % 2) == 0;
  try {
    const auto cloud = pointillist::preprocess::readPointCloud(path, options);
    (void)cloud;
  } catch (const pointillist::InputError&) {
    // Refused with a message naming the file: what a damaged file should get.
  }
  return 0;
}
