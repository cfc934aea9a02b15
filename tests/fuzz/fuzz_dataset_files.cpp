// libFuzzer target: the dataset loader's binary files (every role opens its
// dataset before anything else). A small real dataset (POINTILLIST_FUZZ_DATASET,
// deploy/fuzz.sh preprocesses one from a scan) is copied to a scratch folder
// once; each input replaces one of its files, and the manifest is rewritten
// with that file's size, checksum and the counts its size implies, so inputs
// get past the checksum to the structural checks (as a file from a buggy or
// hostile writer would). Then the dataset is opened whole and every packet is
// read back. An InputError is the refusal damaged data should get; a crash,
// a sanitizer report or any other exception is a finding.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "common/checksum.hpp"
#include "common/dataset.hpp"
#include "common/dataset_manifest.hpp"
#include "common/errors.hpp"

namespace fs = std::filesystem;
using pointillist::DatasetManifest;

namespace {

struct Scratch {
  fs::path dir;
  DatasetManifest manifest;
  // Each file's original bytes, written back after every input. (A copy from
  // the source folder by sendfile fails with EINTR when libFuzzer's timer
  // fires during it; ofstream retries.)
  std::vector<std::string> originals;
};

std::string readWhole(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void writeFile(const fs::path& path, const std::uint8_t* data, std::size_t size) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
}

Scratch& scratch() {
  static Scratch s = [] {
    const char* source = std::getenv("POINTILLIST_FUZZ_DATASET");
    if (source == nullptr) {
      std::fprintf(stderr, "fuzz_dataset_files: set POINTILLIST_FUZZ_DATASET to a small dataset\n");
      std::abort();
    }
    Scratch made;
    const fs::path base = fs::exists("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
    made.dir = base / ("pointillist-fuzz-dataset-" + std::to_string(getpid()));
    fs::remove_all(made.dir);
    fs::create_directories(made.dir);
    for (const auto& entry : fs::directory_iterator(source)) {
      if (!entry.is_regular_file()) continue;
      const std::string bytes = readWhole(entry.path());
      writeFile(made.dir / entry.path().filename(),
                reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
    }
    made.manifest = DatasetManifest::parse(readWhole(made.dir / "manifest.txt"), source);
    for (const auto& file : made.manifest.files) {
      made.originals.push_back(readWhole(made.dir / file.name));
    }
    std::atexit([] { fs::remove_all(scratch().dir); });
    return made;
  }();
  return s;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  Scratch& s = scratch();
  DatasetManifest manifest = s.manifest;
  // The first byte picks the file; the rest is its new content.
  const std::size_t which = data[0] % manifest.files.size();
  pointillist::DatasetFile& file = manifest.files[which];
  const std::uint8_t* content = data + 1;
  const std::size_t bytes = size - 1;
  file.size = bytes;
  if (file.checksum) file.checksum = pointillist::checksum64(content, bytes);
  // Counts follow the file's size where its records have a fixed size, so the
  // size checks pass and the contents are what is judged.
  if (file.key == "cells" && bytes % 64 == 0) manifest.cellCount = bytes / 64;
  if (file.key == "top_level" && bytes % 32 == 0) manifest.topLevelCount = bytes / 32;
  writeFile(s.dir / file.name, content, bytes);
  const std::string text = manifest.toText();
  writeFile(s.dir / "manifest.txt", reinterpret_cast<const std::uint8_t*>(text.data()),
            text.size());
  try {
    const auto dataset = pointillist::Dataset::open(s.dir, pointillist::DatasetParts::All);
    for (std::uint32_t i = 0; i < dataset.topLevelCells().size(); ++i) {
      (void)dataset.readTopLevel(i);
      (void)dataset.packet(i);
      (void)dataset.packetChecksum(i);
    }
  } catch (const pointillist::InputError&) {
  }
  // The original file again for the next input.
  const std::string& original = s.originals[which];
  writeFile(s.dir / file.name, reinterpret_cast<const std::uint8_t*>(original.data()),
            original.size());
  return 0;
}
