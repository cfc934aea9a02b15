#pragma once
// What the preprocess hands to the dataset writer, and the writer itself
// (layout of the directory: common/dataset.hpp).
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "common/dataset_manifest.hpp"
#include "common/octree_cell.hpp"
#include "common/splat.hpp"

namespace pointillist {

// What the preprocess hands to the writer. Packets are not materialized: top-
// level cell k's packet is its levelSplatCount splats from `levelSplats`
// (already layered coarse-first) followed by its pointCount splats from
// `points`, both taken in table order.
struct DatasetContent {
  DatasetManifest manifest;  // descriptive fields; counts, files, checksums are filled in
  std::vector<OctreeCell> cells;
  std::vector<TopLevelCell> topLevel;  // byteOffset/byteSize are filled in
  std::vector<Splat> points;
  std::vector<Splat> levelSplats;
  // --instanced: the packets' instanced sections (32-byte records, table order;
  // TopLevelCell::instancedRecordCount each). Empty otherwise.
  std::vector<Splat> instancedRecords;
  // Files of later stages (statistical hierarchy, transformation streams),
  // written verbatim with a checksum and listed as file.<key>.
  struct ExtraFile {
    std::string key;
    std::string name;
    std::vector<std::byte> bytes;
  };
  std::vector<ExtraFile> extraFiles;
};

// Fills the manifest counts, bounds, largest splat radius and file list
// (sizes; checksums are left to the writer) and the table's byteOffset/byteSize, then validates the
// structure. Counts come from the top-level table; `points`/`levelSplats`, when
// not empty, must agree with it. Throws Error("internal error: ...") when
// content is inconsistent. writeDataset calls it; tests and in-memory users may
// call it directly.
void finalizeDatasetContent(DatasetContent& content);

// (bytes done, bytes total)
using DatasetProgressFn = std::function<void(std::uint64_t, std::uint64_t)>;

// Validates `content`, writes it into `<dir>.tmp-XXXXXX` next to `dir` and
// renames that to `dir` at the end; on any failure the temporary directory is
// removed. An existing `dir` is replaced only when `overwrite` is set (else
// UsageError). Completes content.manifest and content.topLevel in place and
// returns the bytes written.
std::uint64_t writeDataset(const std::filesystem::path& dir, DatasetContent& content,
                           bool overwrite = false, const DatasetProgressFn& progress = {});

// The same, packet by packet, for content that never sits in memory whole (the
// out-of-core preprocess): the constructor checks the output and creates the
// temporary directory, appendPacket streams top-level cell k's packet in table
// order into points.bin, and commit writes the rest from `content` (whose
// points/levelSplats stay empty) and renames the directory into place. A writer
// destroyed without commit removes everything it wrote.
class DatasetWriter {
 public:
  DatasetWriter(const std::filesystem::path& dir, bool overwrite = false);
  ~DatasetWriter();
  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;

  void appendPacket(std::span<const Splat> levelSplats, std::span<const Splat> instancedRecords,
                    std::span<const Splat> points);
  std::uint64_t packetsAppended() const;
  std::uint64_t bytesAppended() const;
  // Throws Error("internal error: ...") when the appended packets do not match
  // content.topLevel. Returns the bytes written.
  std::uint64_t commit(DatasetContent& content);

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace pointillist
