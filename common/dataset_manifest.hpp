#pragma once
// manifest.txt of a dataset directory (see common/dataset.hpp for the files it
// lists): `key = value` lines with the format version, bounds, the largest
// splat radius, counts, build options, and one
// `file.<key> = <name> <bytes> <checksum|->` line per file.
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "common/octree_cell.hpp"
#include "common/splat.hpp"

namespace pointillist {

// 2: max_splat_radius, so a process that needs only the manifest need not load cells.bin.
// 3: checksums are XXH3-64 (common/checksum.hpp) instead of FNV-1a 64.
// 4: packets are layered coarse-first (level-splats by level, then the points),
//    so a prefix of a packet is a level of detail (common/dataset.hpp).
inline constexpr std::uint32_t kDatasetFormatVersion = 4;
inline constexpr const char* kChecksumName = "xxh3-64";

struct DatasetFile {
  std::string key;   // cells, top_level, packet_checksums, points, or a later stage's key
  std::string name;  // file name inside the dataset directory
  std::uint64_t size = 0;
  std::optional<std::uint64_t> checksum;  // checksum64 of the whole file; none for points
};

struct DatasetManifest {
  std::uint32_t formatVersion = kDatasetFormatVersion;
  std::string source;              // input files or generator, for humans
  std::string createdBy;           // tool and version
  float boundsMin[3] = {0, 0, 0};  // tight bounds of all splat centres
  float boundsMax[3] = {0, 0, 0};
  float maxSplatRadius = 0;  // largest splat radius of the dataset: the root cell's
  std::uint64_t pointCount = 0;
  std::uint64_t levelSplatCount = 0;
  std::uint64_t instancedRecordCount = 0;  // --instanced: the packets' instanced sections
  std::uint64_t cellCount = 0;
  std::uint64_t topLevelCount = 0;
  std::uint32_t topLevelDepth = 0;
  std::uint32_t treeDepth = 0;  // deepest cell
  std::uint32_t maxLevel = 0;   // level of the root
  // Build options, recorded so a dataset can be reproduced.
  std::uint32_t maxDepth = 0;
  std::uint32_t leafPoints = 0;
  double levelSplatReduction = 0;
  std::uint32_t recordSize = sizeof(Splat);
  std::uint32_t cellSize = sizeof(OctreeCell);
  std::uint32_t topLevelEntrySize = sizeof(TopLevelCell);
  std::vector<DatasetFile> files;
  // Keys this version does not know; kept so later stages can add their own.
  std::map<std::string, std::string> extra;

  const DatasetFile* file(std::string_view key) const;
  std::string toText() const;
  // Throws InputError naming `where` and the line for malformed text, unknown
  // format or version (an older one is told to run pointillist-preprocess
  // again), missing required keys and a bad max_splat_radius.
  static DatasetManifest parse(std::string_view text, const std::string& where);
};

}  // namespace pointillist
