#pragma once
// Shared by the dataset's manifest, reader and writer; not part of the public face.
#include <bit>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

namespace pointillist::dataset_detail {

static_assert(std::endian::native == std::endian::little,
              "dataset files are little-endian raw records");

inline constexpr const char* kManifestName = "manifest.txt";
inline constexpr const char* kFormatName = "pointillist-dataset";

struct FileSpec {
  const char* key;
  const char* name;
};
inline constexpr FileSpec kCellsFile{"cells", "cells.bin"};
inline constexpr FileSpec kTopLevelFile{"top_level", "top-level.bin"};
inline constexpr FileSpec kChecksumsFile{"packet_checksums", "packet-checksums.bin"};
inline constexpr FileSpec kPointsFile{"points", "points.bin"};

std::string hex64(std::uint64_t v);
std::string floatText(float v);  // shortest text that reads back to the same float
std::string_view trim(std::string_view s);
bool isPlainFileName(std::string_view name);
std::string quoted(const std::filesystem::path& p);

}  // namespace pointillist::dataset_detail
