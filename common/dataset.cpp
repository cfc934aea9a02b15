// Reading a dataset directory: the manifest, file presence and sizes,
// checksums, and the structural validation that refuses damaged or
// mismatched datasets.
#include "common/dataset.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <system_error>

#include "common/checksum.hpp"
#include "common/dataset_internal.hpp"
#include "common/errors.hpp"

namespace pointillist {

using dataset_detail::FileSpec;
using dataset_detail::floatText;
using dataset_detail::hex64;
using dataset_detail::kCellsFile;
using dataset_detail::kChecksumsFile;
using dataset_detail::kManifestName;
using dataset_detail::kPointsFile;
using dataset_detail::kTopLevelFile;
using dataset_detail::quoted;
namespace fs = std::filesystem;

namespace {

std::vector<char> readWholeFile(const fs::path& path, std::uint64_t expectedSize) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string() + ": cannot open: " + std::strerror(errno));
  std::vector<char> bytes(static_cast<std::size_t>(expectedSize));
  in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (static_cast<std::uint64_t>(in.gcount()) != expectedSize)
    throw InputError(path.string() + ": short read (" + std::to_string(in.gcount()) + " of " +
                     std::to_string(expectedSize) + " bytes): truncated file");
  return bytes;
}

template <class T, class Byte>
std::vector<T> asRecords(const std::vector<Byte>& bytes) {
  std::vector<T> out(bytes.size() / sizeof(T));
  if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size() * sizeof(T));
  return out;
}

}  // namespace

// ---------------------------------------------------------------- validation

void validateDatasetStructure(const DatasetManifest& m, std::span<const OctreeCell> cells,
                              std::span<const TopLevelCell> topLevel, const std::string& where) {
  const std::string tlWhere =
      where + "/" +
      (m.file(kTopLevelFile.key) ? m.file(kTopLevelFile.key)->name : kTopLevelFile.name);
  const std::string cellWhere =
      where + "/" + (m.file(kCellsFile.key) ? m.file(kCellsFile.key)->name : kCellsFile.name);

  // Top-level table: contiguous packets that exactly cover the point-array.
  if (topLevel.size() != m.topLevelCount)
    throw InputError(tlWhere + ": " + std::to_string(topLevel.size()) + " entries, manifest says " +
                     std::to_string(m.topLevelCount));
  if (m.pointCount == 0 || m.topLevelCount == 0 || m.cellCount == 0)
    throw InputError(where + "/" + kManifestName +
                     ": empty dataset (no points, cells or top-level cells)");
  std::uint64_t offset = 0, points = 0, splats = 0, instanced = 0;
  for (std::size_t k = 0; k < topLevel.size(); ++k) {
    const TopLevelCell& t = topLevel[k];
    const std::string at = tlWhere + ": entry " + std::to_string(k) + ": ";
    if (t.pointCount == 0) throw InputError(at + "no points");
    if (t.byteOffset != offset)
      throw InputError(at + "byte offset " + std::to_string(t.byteOffset) + ", expected " +
                       std::to_string(offset) + " (packets must be contiguous)");
    const std::uint64_t size = packetRecords(t) * sizeof(Splat);
    if (t.byteSize != size)
      throw InputError(at + "byte size " + std::to_string(t.byteSize) + " does not match its " +
                       std::to_string(t.pointCount) + " points, " +
                       std::to_string(t.levelSplatCount) + " level-splats and " +
                       std::to_string(t.instancedRecordCount) + " instanced records");
    if (k > 0 && t.cellIndex <= topLevel[k - 1].cellIndex)
      throw InputError(at + "cell index not increasing");
    if (t.cellIndex >= m.cellCount)
      throw InputError(at + "cell index " + std::to_string(t.cellIndex) + " out of range");
    offset += size;
    points += t.pointCount;
    splats += t.levelSplatCount;
    instanced += t.instancedRecordCount;
  }
  if (instanced != m.instancedRecordCount)
    throw InputError(tlWhere + ": packets hold " + std::to_string(instanced) +
                     " instanced records, manifest says " + std::to_string(m.instancedRecordCount));
  if (points != m.pointCount || splats != m.levelSplatCount)
    throw InputError(tlWhere + ": packets hold " + std::to_string(points) + " points and " +
                     std::to_string(splats) + " level-splats, manifest says " +
                     std::to_string(m.pointCount) + " and " + std::to_string(m.levelSplatCount));

  if (cells.empty()) return;
  const std::size_t n = cells.size();
  if (n != m.cellCount)
    throw InputError(cellWhere + ": " + std::to_string(n) + " cells, manifest says " +
                     std::to_string(m.cellCount));
  auto fail = [&](std::size_t i, const std::string& what) {
    throw InputError(cellWhere + ": cell " + std::to_string(i) + ": " + what);
  };
  if (cells[0].depth != 0) fail(0, "the root must have depth 0");

  // Depth-first structure from depths: parent, expected nextSibling, child counts.
  std::vector<std::uint32_t> parent(n, kNoIndex);
  std::vector<std::uint32_t> expectedNext(n, kNoIndex);
  std::vector<std::uint32_t> children(n, 0);
  std::vector<std::uint32_t> stack;
  for (std::size_t i = 0; i < n; ++i) {
    const OctreeCell& c = cells[i];
    if (i > 0 && (c.depth == 0 || c.depth > cells[i - 1].depth + 1))
      fail(i, "depth " + std::to_string(c.depth) + " breaks depth-first order");
    while (!stack.empty() && cells[stack.back()].depth >= c.depth) {
      expectedNext[stack.back()] = static_cast<std::uint32_t>(i);
      stack.pop_back();
    }
    if (!stack.empty()) {
      parent[i] = stack.back();
      ++children[stack.back()];
    }
    stack.push_back(static_cast<std::uint32_t>(i));
  }
  for (std::size_t i = 0; i < n; ++i) {
    const OctreeCell& c = cells[i];
    if (c.nextSibling != kNoIndex && (c.nextSibling <= i || c.nextSibling >= n))
      fail(i, "nextSibling " + std::to_string(c.nextSibling) +
                  " is out of range or not after the cell");
    if (c.nextSibling != expectedNext[i])
      fail(i,
           "nextSibling " + std::to_string(c.nextSibling) + " does not skip exactly its subtree");
    const bool leaf = children[i] == 0;
    if (c.isLeaf() != leaf) fail(i, "leaf flag disagrees with the tree");
    if (c.childCount != children[i]) fail(i, "childCount disagrees with the tree");
    for (int a = 0; a < 3; ++a)
      if (!std::isfinite(c.boundsMin[a]) || !std::isfinite(c.boundsMax[a]) ||
          c.boundsMin[a] > c.boundsMax[a])
        fail(i, "bounds are not finite or inverted");
    if (!std::isfinite(c.maxSplatRadius) || c.maxSplatRadius < 0.0f)
      fail(i, "maxSplatRadius is not a finite non-negative number");
    if (parent[i] != kNoIndex) {
      const OctreeCell& p = cells[parent[i]];
      for (int a = 0; a < 3; ++a)
        if (c.boundsMin[a] < p.boundsMin[a] || c.boundsMax[a] > p.boundsMax[a])
          fail(i, "bounds are not inside the parent's");
      if (c.maxSplatRadius > p.maxSplatRadius) fail(i, "maxSplatRadius exceeds the parent's");
    }
  }
  // Readers that skip cells.bin take the largest radius from the manifest.
  if (cells[0].maxSplatRadius != m.maxSplatRadius)
    throw InputError(cellWhere + ": the root's maxSplatRadius " +
                     floatText(cells[0].maxSplatRadius) + " differs from max_splat_radius " +
                     floatText(m.maxSplatRadius) + " in " + where + "/" + kManifestName);
  // Levels: leaves 1, others 1 + max(children) (seed 003 §4.1.2).
  std::vector<std::uint32_t> childMax(n, 0);
  for (std::size_t j = n; j-- > 0;) {
    const std::uint32_t level = children[j] == 0 ? 1 : 1 + childMax[j];
    if (cells[j].level != level)
      fail(j, "level " + std::to_string(cells[j].level) + ", expected " + std::to_string(level));
    if (parent[j] != kNoIndex) childMax[parent[j]] = std::max(childMax[parent[j]], level);
  }
  // Top-level membership and data ranges inside the packet.
  for (std::size_t k = 0; k < topLevel.size(); ++k) {
    const std::uint32_t ci = topLevel[k].cellIndex;
    if (cells[ci].topLevel != k)
      throw InputError(tlWhere + ": entry " + std::to_string(k) + " names cell " +
                       std::to_string(ci) + " whose topLevel is " +
                       std::to_string(cells[ci].topLevel));
  }
  std::vector<std::uint64_t> leafRun(topLevel.size(), 0);  // next expected leaf offset per packet
  struct LevelRange {
    std::uint32_t offset, count, level;
  };
  std::vector<std::vector<LevelRange>> layers(topLevel.size());  // level-splat ranges per packet
  for (std::size_t i = 0; i < n; ++i) {
    const OctreeCell& c = cells[i];
    const std::uint32_t p = parent[i];
    if (c.topLevel == kNoIndex) {
      if (p != kNoIndex && cells[p].topLevel != kNoIndex)
        fail(i, "has no top-level cell but its parent has");
      if (children[i] == 0)
        fail(i, "leaf without a top-level cell (its points belong to no packet)");
      if (c.depth >= m.topLevelDepth) fail(i, "no top-level cell at or below the top-level depth");
      if (c.pointsCount != 0 || c.splatsCount != 0 || c.pointsOffset != 0 || c.splatsOffset != 0)
        fail(i, "data range above the top-level depth");
      continue;
    }
    if (c.topLevel >= topLevel.size())
      fail(i, "topLevel " + std::to_string(c.topLevel) + " out of range");
    const TopLevelCell& t = topLevel[c.topLevel];
    const bool isRoot = t.cellIndex == i;
    if (isRoot) {
      if (p != kNoIndex && cells[p].topLevel != kNoIndex)
        fail(i, "top-level cell nested in another");
      if (!(c.depth == m.topLevelDepth || (children[i] == 0 && c.depth < m.topLevelDepth)))
        fail(i, "top-level cell at depth " + std::to_string(c.depth) + " (top-level depth " +
                    std::to_string(m.topLevelDepth) + ")");
      if (c.pointsOffset != pointsStart(t) || c.pointsCount != t.pointCount)
        fail(i, "top-level cell's points range is not its whole point part");
    } else if (p == kNoIndex || cells[p].topLevel != c.topLevel) {
      fail(i, "topLevel differs from its parent's");
    }
    // Points start after the level-splats and the instanced section.
    const std::uint64_t P = t.pointCount, L = t.levelSplatCount, S = pointsStart(t);
    if (c.pointsCount == 0) fail(i, "empty cell");
    if (c.pointsOffset < S || std::uint64_t{c.pointsOffset} + c.pointsCount > S + P)
      fail(i, "points range outside its packet's points");
    if (c.splatsCount != 0 && std::uint64_t{c.splatsOffset} + c.splatsCount > L)
      fail(i, "level-splat range outside its packet's level-splats");
    if (c.splatsCount != 0) layers[c.topLevel].push_back({c.splatsOffset, c.splatsCount, c.level});
    if (children[i] == 0) {
      if (c.pointsOffset != S + leafRun[c.topLevel])
        fail(i, "leaf points are not contiguous in depth-first order");
      leafRun[c.topLevel] += c.pointsCount;
    } else if (cells[i + 1].pointsOffset != c.pointsOffset) {
      fail(i, "points range does not start with its first child's");
    }
    if (p != kNoIndex && cells[p].topLevel == c.topLevel &&
        c.pointsOffset + std::uint64_t{c.pointsCount} >
            cells[p].pointsOffset + std::uint64_t{cells[p].pointsCount})
      fail(i, "points range not inside its parent's");
  }
  for (std::size_t k = 0; k < topLevel.size(); ++k) {
    const std::string at = tlWhere + ": entry " + std::to_string(k) + ": ";
    if (leafRun[k] != topLevel[k].pointCount)
      throw InputError(at + "its leaves hold " + std::to_string(leafRun[k]) + " of its " +
                       std::to_string(topLevel[k].pointCount) + " points");
    // Coarse-first layers: the cells' level-splat ranges tile [0, levelSplatCount)
    // without gaps or overlaps, and levels never rise along the packet.
    auto& ranges = layers[k];
    std::sort(ranges.begin(), ranges.end(),
              [](const LevelRange& a, const LevelRange& b) { return a.offset < b.offset; });
    std::uint64_t end = 0;
    for (std::size_t r = 0; r < ranges.size(); ++r) {
      if (ranges[r].offset != end)
        throw InputError(at + "level-splats at " + std::to_string(ranges[r].offset) +
                         (ranges[r].offset < end ? " overlap" : " leave a gap") +
                         " (expected offset " + std::to_string(end) + ")");
      if (r > 0 && ranges[r].level > ranges[r - 1].level)
        throw InputError(at + "level-splats of level " + std::to_string(ranges[r].level) +
                         " follow level " + std::to_string(ranges[r - 1].level) +
                         " (packets must be layered coarse-first)");
      end += ranges[r].count;
    }
    if (end != topLevel[k].levelSplatCount)
      throw InputError(at + "its cells hold " + std::to_string(end) + " of its " +
                       std::to_string(topLevel[k].levelSplatCount) + " level-splats");
  }
}

// ---------------------------------------------------------------- loading

Dataset Dataset::open(const fs::path& dir, DatasetParts parts) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) throw InputError("dataset " + quoted(dir) + ": does not exist");
  if (!fs::is_directory(dir, ec)) throw InputError("dataset " + quoted(dir) + ": not a directory");
  Dataset ds;
  ds.dir_ = dir;
  const fs::path manifestPath = dir / kManifestName;
  if (!fs::is_regular_file(manifestPath, ec))
    throw InputError(manifestPath.string() + ": missing (not a Pointillist dataset?)");
  {
    const auto size = fs::file_size(manifestPath, ec);
    if (ec || size > (1u << 20))
      throw InputError(manifestPath.string() + ": unreadable or too large");
    const auto bytes = readWholeFile(manifestPath, size);
    ds.manifest_ =
        DatasetManifest::parse(std::string_view(bytes.data(), bytes.size()), manifestPath.string());
  }
  const DatasetManifest& m = ds.manifest_;

  // Every listed file must be there with its recorded size, loaded or not.
  for (const DatasetFile& f : m.files) {
    const fs::path p = dir / f.name;
    if (!fs::is_regular_file(p, ec)) throw InputError(p.string() + ": missing");
    const auto size = fs::file_size(p, ec);
    if (ec) throw InputError(p.string() + ": cannot stat: " + ec.message());
    if (size != f.size)
      throw InputError(p.string() + ": " + std::to_string(size) + " bytes, manifest says " +
                       std::to_string(f.size) + " (truncated or damaged)");
  }
  auto expectSize = [&](const FileSpec& spec, std::uint64_t size) {
    const DatasetFile* f = m.file(spec.key);
    if (f->size != size)
      throw InputError(manifestPath.string() + ": file." + spec.key + " size " +
                       std::to_string(f->size) + " does not match the counts (" +
                       std::to_string(size) + " bytes expected)");
  };
  // Counts times record sizes, refused where the product wraps: 2^58 cells of
  // 64 bytes would otherwise match an empty file.
  auto bytesFor = [&](const char* key, std::uint64_t count, std::uint64_t record) {
    if (count > std::numeric_limits<std::uint64_t>::max() / record) {
      throw InputError(manifestPath.string() + ": " + key + " " + std::to_string(count) +
                       " is more than any file can hold");
    }
    return count * record;
  };
  if (m.pointCount > std::numeric_limits<std::uint64_t>::max() / 4 ||
      m.levelSplatCount > std::numeric_limits<std::uint64_t>::max() / 4 ||
      m.instancedRecordCount > std::numeric_limits<std::uint64_t>::max() / 4) {
    throw InputError(manifestPath.string() +
                     ": point_count, level_splat_count or instanced_record_count overflow");
  }
  expectSize(kCellsFile, bytesFor("cell_count", m.cellCount, sizeof(OctreeCell)));
  expectSize(kTopLevelFile, bytesFor("top_level_count", m.topLevelCount, sizeof(TopLevelCell)));
  expectSize(kChecksumsFile, bytesFor("top_level_count", m.topLevelCount, sizeof(std::uint64_t)));
  expectSize(kPointsFile,
             bytesFor("point_count", m.pointCount + m.levelSplatCount + m.instancedRecordCount,
                      sizeof(Splat)));

  auto loadChecked = [&](const FileSpec& spec) {
    const DatasetFile* f = m.file(spec.key);
    const fs::path p = dir / f->name;
    auto bytes = readWholeFile(p, f->size);
    const std::uint64_t sum = checksum64(bytes.data(), bytes.size());
    if (f->checksum && *f->checksum != sum)
      throw InputError(p.string() + ": checksum mismatch (damaged file; manifest " +
                       hex64(*f->checksum) + ", file " + hex64(sum) + ")");
    return bytes;
  };
  if (hasParts(parts, DatasetParts::TopLevel)) {
    ds.topLevel_ = asRecords<TopLevelCell>(loadChecked(kTopLevelFile));
    ds.packetChecksums_ = asRecords<std::uint64_t>(loadChecked(kChecksumsFile));
  }
  if (hasParts(parts, DatasetParts::Cells))
    ds.cells_ = asRecords<OctreeCell>(loadChecked(kCellsFile));
  if (hasParts(parts, DatasetParts::TopLevel)) {
    validateDatasetStructure(m, ds.cells_, ds.topLevel_, dir.string());
    if (m.file(kStatisticalIndexKey) != nullptr) ds.loadStatisticalIndex();
  }
  if (hasParts(parts, DatasetParts::Points)) {
    const DatasetFile* f = m.file(kPointsFile.key);
    const fs::path p = dir / f->name;
    ds.points_ = asRecords<Splat>(readWholeFile(p, f->size));
    for (std::uint32_t k = 0; k < ds.topLevel_.size(); ++k) {
      const auto s = ds.packet(k);
      const std::uint64_t sum = checksum64(s.data(), s.size_bytes());
      if (sum != ds.packetChecksums_[k])
        throw InputError(p.string() + ": top-level cell " + std::to_string(k) + " (bytes " +
                         std::to_string(ds.topLevel_[k].byteOffset) + "+" +
                         std::to_string(ds.topLevel_[k].byteSize) +
                         "): checksum mismatch (damaged file)");
    }
    if (ds.hasStatistical()) {
      const DatasetFile* sf = m.file(kStatisticalPacketsKey);
      ds.statisticalRecords_ = asRecords<Splat>(readWholeFile(dir / sf->name, sf->size));
      for (std::uint32_t t = 0; t < ds.statistical_.size(); ++t) {
        const auto s = ds.packet(ds.statisticalPacketId(t));
        if (checksum64(s.data(), s.size_bytes()) != ds.statistical_[t].checksum)
          throw InputError((dir / sf->name).string() + ": statistical packet of top-level cell " +
                           std::to_string(t) + ": checksum mismatch (damaged file)");
      }
    }
  }
  return ds;
}

void Dataset::loadStatisticalIndex() {
  const DatasetFile* index = manifest_.file(kStatisticalIndexKey);
  const DatasetFile* packets = manifest_.file(kStatisticalPacketsKey);
  const std::string where = (dir_ / index->name).string();
  if (packets == nullptr || manifest_.file(kStatisticalClassesKey) == nullptr)
    throw InputError(where + ": statistical index without " + kStatisticalPacketsName + " and " +
                     kStatisticalClassesName);
  const auto bytes = readFile(kStatisticalIndexKey);
  if (bytes.size() != topLevel_.size() * sizeof(StatisticalPacketEntry))
    throw InputError(where + ": " + std::to_string(bytes.size()) + " bytes, " +
                     std::to_string(topLevel_.size()) + " top-level cells need " +
                     std::to_string(topLevel_.size() * sizeof(StatisticalPacketEntry)));
  statistical_ = asRecords<StatisticalPacketEntry>(bytes);
  std::uint64_t offset = 0;
  for (std::size_t t = 0; t < statistical_.size(); ++t) {
    const StatisticalPacketEntry& e = statistical_[t];
    if (e.byteOffset != offset || e.nodeCount == 0 ||
        statisticalPrefixRecords(e.nodeCount) != e.records)
      throw InputError(where + ": entry " + std::to_string(t) + " (offset " +
                       std::to_string(e.byteOffset) + ", " + std::to_string(e.records) +
                       " records, " + std::to_string(e.nodeCount) +
                       " nodes) does not follow the one before or does not fit its nodes");
    offset += std::uint64_t{e.records} * sizeof(Splat);
  }
  if (offset != packets->size)
    throw InputError(where + ": the packets cover " + std::to_string(offset) + " bytes, " +
                     kStatisticalPacketsName + " has " + std::to_string(packets->size));
}

ClassTables Dataset::readStatisticalClasses() const {
  if (manifest_.file(kStatisticalClassesKey) == nullptr)
    throw UsageError(dir_.string() +
                     " has no statistical hierarchy; build it with pointillist-preprocess "
                     "--statistical");
  return decodeClassTables(readFile(kStatisticalClassesKey),
                           (dir_ / kStatisticalClassesName).string());
}

std::uint64_t Dataset::packetChecksum(std::uint32_t topLevel) const {
  if (topLevel >= packetChecksums_.size() &&
      topLevel - packetChecksums_.size() < statistical_.size())
    return statistical_[topLevel - packetChecksums_.size()].checksum;
  if (topLevel >= packetChecksums_.size())
    throw UsageError("top-level cell " + std::to_string(topLevel) +
                     " out of range or table not loaded");
  return packetChecksums_[topLevel];
}

std::span<const Splat> Dataset::packet(std::uint32_t topLevel) const {
  if (topLevel >= topLevel_.size() && topLevel - topLevel_.size() < statistical_.size() &&
      !statisticalRecords_.empty()) {
    const StatisticalPacketEntry& e = statistical_[topLevel - topLevel_.size()];
    return std::span<const Splat>(statisticalRecords_)
        .subspan(static_cast<std::size_t>(e.byteOffset / sizeof(Splat)), e.records);
  }
  if (topLevel >= topLevel_.size() || points_.empty())
    throw UsageError("top-level cell " + std::to_string(topLevel) +
                     " out of range or points not loaded");
  const TopLevelCell& t = topLevel_[topLevel];
  return std::span<const Splat>(points_).subspan(
      static_cast<std::size_t>(t.byteOffset / sizeof(Splat)),
      static_cast<std::size_t>(t.byteSize / sizeof(Splat)));
}

std::vector<std::byte> Dataset::readFile(std::string_view key) const {
  const DatasetFile* f = manifest_.file(key);
  if (!f)
    throw InputError((dir_ / kManifestName).string() + ": no file." + std::string(key) + " entry");
  const fs::path p = dir_ / f->name;
  std::error_code ec;
  const auto size = fs::file_size(p, ec);
  if (ec) throw InputError(p.string() + ": missing");
  if (size != f->size)
    throw InputError(p.string() + ": " + std::to_string(size) + " bytes, manifest says " +
                     std::to_string(f->size) + " (truncated or damaged)");
  const auto bytes = readWholeFile(p, f->size);
  if (f->checksum && checksum64(bytes.data(), bytes.size()) != *f->checksum)
    throw InputError(p.string() + ": checksum mismatch (damaged file)");
  std::vector<std::byte> out(bytes.size());
  if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size());
  return out;
}

namespace {

// One packet's records from `file` into `out`, verified against its checksum;
// `what` names the packet in errors.
void readPacketAt(const fs::path& file, std::uint64_t byteOffset, std::span<Splat> out,
                  std::uint64_t checksum, const std::string& what) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string() + ": cannot open: " + std::strerror(errno));
  const auto bytes = static_cast<std::streamsize>(out.size_bytes());
  in.seekg(static_cast<std::streamoff>(byteOffset));
  in.read(reinterpret_cast<char*>(out.data()), bytes);
  if (!in || in.gcount() != bytes)
    throw InputError(file.string() + ": " + what + ": short read (truncated file)");
  if (checksum64(out.data(), out.size_bytes()) != checksum)
    throw InputError(file.string() + ": " + what + " (bytes " + std::to_string(byteOffset) + "+" +
                     std::to_string(bytes) + "): checksum mismatch (damaged file)");
}

}  // namespace

std::uint64_t Dataset::packetSplats(std::uint32_t id) const {
  if (id >= topLevel_.size() && id - topLevel_.size() < statistical_.size())
    return statistical_[id - topLevel_.size()].records;
  if (id >= topLevel_.size())
    throw UsageError("top-level cell " + std::to_string(id) + " out of range or table not loaded");
  return topLevel_[id].byteSize / sizeof(Splat);
}

std::vector<Splat> Dataset::readTopLevel(std::uint32_t id) const {
  std::vector<Splat> out(static_cast<std::size_t>(packetSplats(id)));
  readTopLevelInto(id, out);
  return out;
}

void Dataset::readTopLevelInto(std::uint32_t id, std::span<Splat> out) const {
  if (out.size() != packetSplats(id)) {
    throw UsageError("packet " + std::to_string(id) + " holds " + std::to_string(packetSplats(id)) +
                     " splats, not " + std::to_string(out.size()));
  }
  if (id >= topLevel_.size()) {
    const std::uint32_t t = id - static_cast<std::uint32_t>(topLevel_.size());
    const StatisticalPacketEntry& e = statistical_[t];
    readPacketAt(dir_ / manifest_.file(kStatisticalPacketsKey)->name, e.byteOffset, out, e.checksum,
                 "statistical packet of top-level cell " + std::to_string(t));
    return;
  }
  const TopLevelCell& t = topLevel_[id];
  readPacketAt(dir_ / manifest_.file(kPointsFile.key)->name, t.byteOffset, out,
               packetChecksums_[id], "top-level cell " + std::to_string(id));
}

}  // namespace pointillist
