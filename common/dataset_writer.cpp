// Writing a dataset directory: everything goes into a temporary directory next
// to the target, which is renamed into place at the end.
#include "common/dataset_writer.hpp"

#include <stdlib.h>    // mkdtemp
#include <sys/stat.h>  // umask

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <system_error>

#include "common/checksum.hpp"
#include "common/dataset.hpp"
#include "common/dataset_internal.hpp"
#include "common/direct_file_writer.hpp"
#include "common/errors.hpp"

namespace pointillist {

using dataset_detail::isPlainFileName;
using dataset_detail::kCellsFile;
using dataset_detail::kChecksumsFile;
using dataset_detail::kManifestName;
using dataset_detail::kPointsFile;
using dataset_detail::kTopLevelFile;
using dataset_detail::quoted;
using dataset_detail::trim;
namespace fs = std::filesystem;

namespace {

// Removes a temporary directory unless released.
class TempDir {
 public:
  explicit TempDir(fs::path p) : path_(std::move(p)) {}
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  ~TempDir() {
    if (!path_.empty()) {
      std::error_code ec;
      fs::remove_all(path_, ec);
    }
  }
  const fs::path& path() const { return path_; }
  void release() { path_.clear(); }

 private:
  fs::path path_;
};

fs::path makeUniqueDir(const fs::path& base, const char* suffix) {
  std::string templ = base.string() + suffix + "XXXXXX";
  if (mkdtemp(templ.data()) == nullptr)
    throw Error("cannot create a directory next to " + quoted(base) + ": " + std::strerror(errno));
  // mkdtemp makes it private; a dataset gets the usual umask permissions.
  const mode_t mask = ::umask(0);
  ::umask(mask);
  std::error_code ec;
  fs::permissions(templ, static_cast<fs::perms>(0777 & ~mask), ec);
  return fs::path(templ);
}

class HashingWriter {
 public:
  explicit HashingWriter(const fs::path& p, bool hash = true)
      : path_(p), out_(p, std::ios::binary | std::ios::trunc), hashing_(hash) {
    if (!out_) throw Error("cannot create " + p.string() + ": " + std::strerror(errno));
  }
  void write(const void* data, std::size_t size) {
    out_.write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
    if (!out_) throw Error("cannot write " + path_.string() + ": " + std::strerror(errno));
    if (hashing_) hash_.update(data, size);
    size_ += size;
  }
  DatasetFile finish(const char* key) {
    out_.close();
    if (!out_) throw Error("cannot write " + path_.string() + ": " + std::strerror(errno));
    DatasetFile f{key, path_.filename().string(), size_, std::nullopt};
    if (hashing_) f.checksum = hash_.digest();
    return f;
  }

 private:
  fs::path path_;
  std::ofstream out_;
  bool hashing_;
  ChecksumStream hash_;
  std::uint64_t size_ = 0;
};

bool looksLikeDataset(const fs::path& dir) {
  std::error_code ec;
  if (fs::is_directory(dir, ec) && fs::is_empty(dir, ec)) return true;
  std::ifstream in(dir / kManifestName);
  std::string line;
  while (std::getline(in, line)) {
    const auto t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    return t.rfind("format = pointillist-dataset", 0) == 0;
  }
  return false;
}

}  // namespace

void finalizeDatasetContent(DatasetContent& content) {
  DatasetManifest& m = content.manifest;
  std::uint64_t pointCount = 0, levelSplatCount = 0, instancedRecordCount = 0;
  for (const auto& t : content.topLevel) {
    pointCount += t.pointCount;
    levelSplatCount += t.levelSplatCount;
    instancedRecordCount += t.instancedRecordCount;
  }
  if (content.cells.empty() || content.topLevel.empty() || pointCount == 0)
    throw Error("refusing to write an empty dataset");
  if ((!content.points.empty() && content.points.size() != pointCount) ||
      (!content.points.empty() && content.instancedRecords.size() != instancedRecordCount) ||
      (!content.levelSplats.empty() && content.levelSplats.size() != levelSplatCount))
    throw Error("internal error: inconsistent dataset: the top-level table counts " +
                std::to_string(pointCount) + " points and " + std::to_string(levelSplatCount) +
                " level-splats, the content holds " + std::to_string(content.points.size()) +
                " and " + std::to_string(content.levelSplats.size()));
  m.formatVersion = kDatasetFormatVersion;
  m.recordSize = sizeof(Splat);
  m.cellSize = sizeof(OctreeCell);
  m.topLevelEntrySize = sizeof(TopLevelCell);
  m.pointCount = pointCount;
  m.levelSplatCount = levelSplatCount;
  m.instancedRecordCount = instancedRecordCount;
  m.cellCount = content.cells.size();
  m.topLevelCount = content.topLevel.size();
  m.maxLevel = content.cells[0].level;
  m.maxSplatRadius = content.cells[0].maxSplatRadius;
  m.treeDepth = 0;
  for (const auto& c : content.cells) m.treeDepth = std::max<std::uint32_t>(m.treeDepth, c.depth);
  for (int a = 0; a < 3; ++a) {
    m.boundsMin[a] = content.cells[0].boundsMin[a];
    m.boundsMax[a] = content.cells[0].boundsMax[a];
  }
  std::uint64_t offset = 0;
  for (auto& t : content.topLevel) {
    t.byteOffset = offset;
    t.byteSize = packetRecords(t) * sizeof(Splat);
    offset += t.byteSize;
  }
  m.files = {
      {kCellsFile.key, kCellsFile.name, m.cellCount * sizeof(OctreeCell), std::nullopt},
      {kTopLevelFile.key, kTopLevelFile.name, m.topLevelCount * sizeof(TopLevelCell), std::nullopt},
      {kChecksumsFile.key, kChecksumsFile.name, m.topLevelCount * 8, std::nullopt},
      {kPointsFile.key, kPointsFile.name, offset, std::nullopt}};
  try {
    validateDatasetStructure(m, content.cells, content.topLevel, "(dataset content)");
  } catch (const InputError& e) {
    throw Error(std::string("internal error: inconsistent dataset: ") + e.what());
  }
}

struct DatasetWriter::State {
  fs::path dir;
  bool exists = false;
  TempDir tmp;
  // No whole-file hash for points.bin: the packet checksums cover it. Written
  // direct where it can be (common/direct_file_writer.hpp).
  DirectFileWriter points;
  std::vector<std::uint64_t> packetSums;
  std::vector<std::uint64_t> packetSplats;  // level-splats + points per packet
  std::uint64_t bytes = 0;

  State(fs::path d, bool e, fs::path t)
      : dir(std::move(d)), exists(e), tmp(std::move(t)), points(tmp.path() / kPointsFile.name) {}
};

DatasetWriter::DatasetWriter(const fs::path& dirIn, bool overwrite) {
  fs::path dir = dirIn.lexically_normal();
  if (dir.filename().empty() && dir.has_parent_path()) dir = dir.parent_path();  // "ds/"
  if (dir.filename().empty() || dir.filename() == "." || dir.filename() == "..")
    throw UsageError("output " + quoted(dirIn) + " has no directory name");
  std::error_code ec;
  const bool exists = fs::exists(fs::symlink_status(dir, ec));
  if (exists && !overwrite) throw UsageError("output " + quoted(dir) + " already exists");
  if (exists && !looksLikeDataset(dir))
    throw UsageError("refusing to replace " + quoted(dir) + ": it is not a Pointillist dataset");
  if (!dir.parent_path().empty()) fs::create_directories(dir.parent_path(), ec);
  fs::path tmp = makeUniqueDir(dir, ".tmp-");
  try {
    state_ = std::make_unique<State>(dir, exists, tmp);
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

DatasetWriter::~DatasetWriter() = default;

void DatasetWriter::appendPacket(std::span<const Splat> levelSplats,
                                 std::span<const Splat> instancedRecords,
                                 std::span<const Splat> points) {
  State& s = *state_;
  ChecksumStream packetSum;
  for (const auto part : {levelSplats, instancedRecords, points}) {
    s.points.write(part.data(), part.size_bytes());
    packetSum.update(part.data(), part.size_bytes());
    s.bytes += part.size_bytes();
  }
  s.packetSums.push_back(packetSum.digest());
  s.packetSplats.push_back(levelSplats.size() + instancedRecords.size() + points.size());
}

std::uint64_t DatasetWriter::packetsAppended() const {
  return state_->packetSums.size();
}
std::uint64_t DatasetWriter::bytesAppended() const {
  return state_->bytes;
}

std::uint64_t DatasetWriter::commit(DatasetContent& content) {
  State& s = *state_;
  finalizeDatasetContent(content);
  DatasetManifest& m = content.manifest;
  if (s.packetSplats.size() != content.topLevel.size())
    throw Error("internal error: " + std::to_string(s.packetSplats.size()) +
                " packets written for " + std::to_string(content.topLevel.size()) +
                " top-level cells");
  for (std::size_t k = 0; k < content.topLevel.size(); ++k) {
    const TopLevelCell& t = content.topLevel[k];
    if (s.packetSplats[k] != packetRecords(t))
      throw Error("internal error: packet " + std::to_string(k) + " holds " +
                  std::to_string(s.packetSplats[k]) + " records, the table says " +
                  std::to_string(packetRecords(t)));
  }

  std::vector<DatasetFile> files;
  {
    HashingWriter w(s.tmp.path() / kCellsFile.name);
    w.write(content.cells.data(), content.cells.size() * sizeof(OctreeCell));
    files.push_back(w.finish(kCellsFile.key));
  }
  files.push_back(DatasetFile{kPointsFile.key, kPointsFile.name, s.points.finish(), std::nullopt});
  {
    HashingWriter w(s.tmp.path() / kTopLevelFile.name);
    w.write(content.topLevel.data(), content.topLevel.size() * sizeof(TopLevelCell));
    files.push_back(w.finish(kTopLevelFile.key));
  }
  {
    HashingWriter w(s.tmp.path() / kChecksumsFile.name);
    w.write(s.packetSums.data(), s.packetSums.size() * sizeof(std::uint64_t));
    files.push_back(w.finish(kChecksumsFile.key));
  }
  for (const auto& x : content.extraFiles) {
    if (!isPlainFileName(x.name) || x.name == kManifestName || x.key.empty() ||
        x.key.find_first_of(" \t=") != std::string::npos)
      throw Error("bad extra dataset file '" + x.key + "' -> '" + x.name + "'");
    for (const auto& f : files)
      if (f.key == x.key || f.name == x.name) throw Error("duplicate dataset file '" + x.key + "'");
    HashingWriter w(s.tmp.path() / x.name);
    w.write(x.bytes.data(), x.bytes.size());
    files.push_back(w.finish(x.key.c_str()));
  }
  m.files = std::move(files);
  std::uint64_t bytes = 0;
  for (const auto& f : m.files) bytes += f.size;
  {
    const std::string text = m.toText();
    bytes += text.size();
    std::ofstream out(s.tmp.path() / kManifestName, std::ios::binary | std::ios::trunc);
    out << text;
    out.close();
    if (!out) throw Error("cannot write " + (s.tmp.path() / kManifestName).string());
  }

  // Swap into place: the old dataset (if replacing) moves aside first.
  std::error_code ec;
  const fs::path& dir = s.dir;
  if (s.exists) {
    const fs::path old = makeUniqueDir(dir, ".old-");
    fs::rename(dir, old, ec);  // replaces the empty placeholder
    if (ec) {
      fs::remove(old);
      throw Error("cannot move " + quoted(dir) + " aside: " + ec.message());
    }
    fs::rename(s.tmp.path(), dir, ec);
    if (ec) {
      std::error_code ec2;
      fs::rename(old, dir, ec2);
      throw Error("cannot rename " + quoted(s.tmp.path()) + " to " + quoted(dir) + ": " +
                  ec.message());
    }
    fs::remove_all(old, ec);
  } else {
    fs::rename(s.tmp.path(), dir, ec);
    if (ec)
      throw Error("cannot rename " + quoted(s.tmp.path()) + " to " + quoted(dir) + ": " +
                  ec.message());
  }
  s.tmp.release();
  return bytes;
}

std::uint64_t writeDataset(const fs::path& dir, DatasetContent& content, bool overwrite,
                           const DatasetProgressFn& progress) {
  DatasetWriter writer(dir, overwrite);
  finalizeDatasetContent(content);
  if (content.points.empty() && content.manifest.pointCount > 0)
    throw Error("internal error: writeDataset needs the points in memory");
  const std::uint64_t total = content.manifest.file(kPointsFile.key)->size;
  std::size_t p = 0, s = 0, r = 0;
  for (std::size_t k = 0; k < content.topLevel.size(); ++k) {
    const TopLevelCell& t = content.topLevel[k];
    writer.appendPacket(
        std::span<const Splat>(content.levelSplats).subspan(s, t.levelSplatCount),
        std::span<const Splat>(content.instancedRecords).subspan(r, t.instancedRecordCount),
        std::span<const Splat>(content.points).subspan(p, t.pointCount));
    p += t.pointCount;
    s += t.levelSplatCount;
    r += t.instancedRecordCount;
    if (progress && (k & 63) == 0) progress(writer.bytesAppended(), total);
  }
  if (progress) progress(writer.bytesAppended(), total);
  return writer.commit(content);
}

}  // namespace pointillist
