#pragma once
// The dataset directory written by pointillist-preprocess (SPEC "Dataset"):
//
//   manifest.txt          key = value lines: version, bounds, largest splat radius,
//                         counts, options, and one `file.<key> = <name> <bytes> <xxh3-64|->`
//                         line per file (common/dataset_manifest.hpp)
//   cells.bin             octree-cell-array: OctreeCell[cell_count], depth-first (seed 003 §4.1.1)
//   top-level.bin         TopLevelCell[top_level_count], in depth-first order of their cells
//   packet-checksums.bin  uint64 XXH3-64 (common/checksum.hpp) of each top-level cell's packet,
//                         same order
//   points.bin            point-array: the packets back to back; a packet is one
//                         contiguous byte range, layered coarse-first: the
//                         level-splats of every cell beneath the top-level cell by
//                         level from the highest down (one layer per level; cells
//                         of a layer in depth-first order, each cell's own splats
//                         contiguous), then (datasets built with --instanced) the
//                         cell's instanced section (common/instanced_section.hpp),
//                         then the original points (depth-first leaf
//                         order). A prefix that ends on a layer boundary holds
//                         every cell of those levels, so a render process that
//                         draws a cell coarsely holds and receives only a prefix.
//
// All binary files are little-endian raw records (Splat 32 B, OctreeCell 64 B,
// TopLevelCell 32 B). points.bin has no whole-file checksum: the per-packet
// checksums cover it completely, so a data-send process verifies only its part.
//
// Level of detail (the contract with traverse): a cell's level-splats stand for
// its whole subtree with about 1/4 of the splats of the level below (leaves:
// 1/4 of their points); each level-splat's sphere contains the spheres of the
// splats it replaces, so coarser levels have no holes where finer ones had
// none. OctreeCell::maxSplatRadius is the largest radius of any splat in the
// subtree (points and level-splats; it never grows going down the tree; for a
// cell with level-splats it is their largest radius; the root's is also the
// manifest's max_splat_radius), so
//   - culling: a cell's splats lie inside [boundsMin - r, boundsMax + r] with
//     r = maxSplatRadius (bounds are the tight bounds of the splat centres);
//   - LOD: draw the cell's level-splats (splatsOffset/splatsCount) when
//     maxSplatRadius projects to at most `lod_pixels` (about 1-2) on screen at
//     the cell's nearest point; otherwise descend (index + 1), or at a leaf draw
//     its points (pointsOffset/pointsCount). Cells above the top-level depth
//     (topLevel == kNoIndex) have no data: always descend.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/dataset_manifest.hpp"
#include "common/dataset_writer.hpp"
#include "common/octree_cell.hpp"
#include "common/splat.hpp"
#include "common/statistical_node.hpp"

namespace pointillist {

// Which parts Dataset::open loads into memory. The manifest is always read and
// every listed file is checked for presence and size.
enum class DatasetParts : unsigned {
  Manifest = 0,    // bounds, counts, largest splat radius (display)
  TopLevel = 1,    // top-level table + packet checksums (data-send)
  Cells = 2 | 1,   // + octree-cell-array, validated (traverse)
  Points = 4 | 1,  // + the whole point-array, every packet verified (render, reference)
  All = 7,
};
constexpr DatasetParts operator|(DatasetParts a, DatasetParts b) {
  return static_cast<DatasetParts>(static_cast<unsigned>(a) | static_cast<unsigned>(b));
}
constexpr bool hasParts(DatasetParts set, DatasetParts wanted) {
  return (static_cast<unsigned>(set) & static_cast<unsigned>(wanted)) ==
         static_cast<unsigned>(wanted);
}

class Dataset {
 public:
  // Throws InputError naming the file and the problem: missing files, wrong
  // format version, size or checksum mismatch, inconsistent cell array.
  static Dataset open(const std::filesystem::path& dir, DatasetParts parts = DatasetParts::All);

  const std::filesystem::path& path() const { return dir_; }
  const DatasetManifest& manifest() const { return manifest_; }
  std::span<const OctreeCell> cells() const { return cells_; }               // needs Cells
  std::span<const TopLevelCell> topLevelCells() const { return topLevel_; }  // needs TopLevel
  std::uint64_t packetChecksum(std::uint32_t id) const;  // needs TopLevel; any packet id

  // Packets are addressed by id: top-level cell t's packet is id t; a dataset
  // built with --statistical also has t's statistical packet
  // (common/statistical_node.hpp) as id topLevelCount + t, in statistical.bin.
  // Data-send processes, render caches and prefixes treat both alike.
  std::uint32_t packetCount() const {
    return static_cast<std::uint32_t>(topLevel_.size() + statistical_.size());
  }
  bool hasStatistical() const { return !statistical_.empty(); }  // needs TopLevel
  std::uint32_t statisticalPacketId(std::uint32_t topLevel) const {
    return static_cast<std::uint32_t>(topLevel_.size()) + topLevel;
  }
  std::span<const StatisticalPacketEntry> statisticalPackets() const { return statistical_; }

  // Reads one packet (a top-level cell's from points.bin, a statistical one
  // from statistical.bin) and verifies its checksum (throws InputError on a
  // short read or mismatch). Thread-safe.
  std::vector<Splat> readTopLevel(std::uint32_t id) const;  // needs TopLevel
  // The same into `out`, which must hold exactly packetSplats(id) records.
  void readTopLevelInto(std::uint32_t id, std::span<Splat> out) const;
  std::uint64_t packetSplats(std::uint32_t id) const;  // needs TopLevel

  // The whole point-array and one packet of it in memory (needs Points; the
  // statistical packets are then in memory too).
  std::span<const Splat> points() const { return points_; }
  std::span<const Splat> packet(std::uint32_t id) const;
  // The class tables of a dataset built with --statistical (statistical-classes.bin).
  ClassTables readStatisticalClasses() const;

  // Reads any listed file whole (e.g. a later stage's extra file) and verifies
  // its checksum. Throws InputError when the key is not in the manifest.
  std::vector<std::byte> readFile(std::string_view key) const;

 private:
  void loadStatisticalIndex();

  std::filesystem::path dir_;
  DatasetManifest manifest_;
  std::vector<OctreeCell> cells_;
  std::vector<TopLevelCell> topLevel_;
  std::vector<std::uint64_t> packetChecksums_;
  std::vector<Splat> points_;
  std::vector<StatisticalPacketEntry> statistical_;
  std::vector<Splat> statisticalRecords_;
};

// Checks the top-level table against the manifest (contiguous packets that
// cover the point-array, sizes) and, when `cells` is not empty, the cell array
// (depth-first structure, nextSibling, levels, leaf flags, top-level
// membership, data ranges inside their packet, finite bounds, the root's
// maxSplatRadius against the manifest's). Throws InputError prefixed with
// `where`.
void validateDatasetStructure(const DatasetManifest& manifest, std::span<const OctreeCell> cells,
                              std::span<const TopLevelCell> topLevel, const std::string& where);

}  // namespace pointillist
