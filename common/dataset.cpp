#include "common/dataset.hpp"

#include <stdlib.h>    // mkdtemp
#include <sys/stat.h>  // umask

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>
#include <system_error>

#include "common/errors.hpp"

namespace pointillist {

static_assert(std::endian::native == std::endian::little,
              "dataset files are little-endian raw records");

namespace fs = std::filesystem;

namespace {

constexpr const char* kManifestName = "manifest.txt";
constexpr const char* kFormatName = "pointillist-dataset";
constexpr const char* kRecordLayout = "position:f32x3 normal:f32x3 radius:f32 color:u8x4";

struct FileSpec {
  const char* key;
  const char* name;
};
constexpr FileSpec kCellsFile{"cells", "cells.bin"};
constexpr FileSpec kTopLevelFile{"top_level", "top-level.bin"};
constexpr FileSpec kChecksumsFile{"packet_checksums", "packet-checksums.bin"};
constexpr FileSpec kPointsFile{"points", "points.bin"};

std::string hex64(std::uint64_t v) {
  char buf[17];
  auto r = std::to_chars(buf, buf + sizeof buf, v, 16);
  std::string s(buf, r.ptr);
  return std::string(16 - s.size(), '0') + s;
}

std::string floatText(float v) {
  char buf[32];
  auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

std::string_view trim(std::string_view s) {
  const auto first = s.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = s.find_last_not_of(" \t\r");
  return s.substr(first, last - first + 1);
}

std::vector<std::string_view> words(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && (s[i] == ' ' || s[i] == '\t')) ++i;
    const std::size_t b = i;
    while (i < s.size() && s[i] != ' ' && s[i] != '\t') ++i;
    if (i > b) out.push_back(s.substr(b, i - b));
  }
  return out;
}

template <class T>
bool parseNumber(std::string_view s, T& out, int base = 10) {
  const char* end = s.data() + s.size();
  std::from_chars_result r;
  if constexpr (std::is_floating_point_v<T>) {
    (void)base;
    r = std::from_chars(s.data(), end, out);
  } else {
    r = std::from_chars(s.data(), end, out, base);
  }
  return !s.empty() && r.ec == std::errc() && r.ptr == end;
}

bool isPlainFileName(std::string_view name) {
  return !name.empty() && name != "." && name != ".." && name.find('/') == std::string_view::npos &&
         name.find('\\') == std::string_view::npos;
}

std::string oneLine(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  std::replace(s.begin(), s.end(), '\r', ' ');
  return s;
}

std::string quoted(const fs::path& p) {
  std::string s = p.string();
  s.insert(s.begin(), '\'');
  s.push_back('\'');
  return s;
}

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

template <class T>
std::vector<T> asRecords(const std::vector<char>& bytes) {
  std::vector<T> out(bytes.size() / sizeof(T));
  if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size() * sizeof(T));
  return out;
}

}  // namespace

std::uint64_t fnv1a64(const void* data, std::size_t size, std::uint64_t state) {
  const auto* p = static_cast<const unsigned char*>(data);
  constexpr std::uint64_t kPrime = 0x100000001b3ull;
  for (std::size_t i = 0; i < size; ++i) {
    state ^= p[i];
    state *= kPrime;
  }
  return state;
}

// ---------------------------------------------------------------- manifest

const DatasetFile* DatasetManifest::file(std::string_view key) const {
  for (const auto& f : files)
    if (f.key == key) return &f;
  return nullptr;
}

std::string DatasetManifest::toText() const {
  std::ostringstream o;
  auto vec = [](const float* v) {
    return floatText(v[0]) + " " + floatText(v[1]) + " " + floatText(v[2]);
  };
  o << "# Pointillist dataset manifest: key = value. Binary files are little-endian\n"
       "# raw records; see common/dataset.hpp for the layout.\n";
  o << "format = " << kFormatName << "\n";
  o << "format_version = " << formatVersion << "\n";
  o << "created_by = " << oneLine(createdBy) << "\n";
  o << "source = " << oneLine(source) << "\n";
  o << "byte_order = little\n";
  o << "record_size = " << recordSize << "\n";
  o << "record_layout = " << kRecordLayout << "\n";
  o << "cell_size = " << cellSize << "\n";
  o << "top_level_entry_size = " << topLevelEntrySize << "\n";
  o << "bounds_min = " << vec(boundsMin) << "\n";
  o << "bounds_max = " << vec(boundsMax) << "\n";
  o << "point_count = " << pointCount << "\n";
  o << "level_splat_count = " << levelSplatCount << "\n";
  o << "cell_count = " << cellCount << "\n";
  o << "top_level_count = " << topLevelCount << "\n";
  o << "top_level_depth = " << topLevelDepth << "\n";
  o << "tree_depth = " << treeDepth << "\n";
  o << "max_level = " << maxLevel << "\n";
  o << "max_depth = " << maxDepth << "\n";
  o << "leaf_points = " << leafPoints << "\n";
  o << "level_splat_reduction = " << levelSplatReduction << "\n";
  o << "checksum = fnv1a64\n";
  for (const auto& [k, v] : extra) o << k << " = " << oneLine(v) << "\n";
  for (const auto& f : files)
    o << "file." << f.key << " = " << f.name << " " << f.size << " "
      << (f.checksum ? hex64(*f.checksum) : std::string("-")) << "\n";
  return o.str();
}

DatasetManifest DatasetManifest::parse(std::string_view text, const std::string& where) {
  std::map<std::string, std::pair<std::string, int>> values;  // key -> (value, line)
  std::vector<DatasetFile> files;
  std::set<std::string> fileKeys;
  int lineNo = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    std::size_t nl = text.find('\n', pos);
    if (nl == std::string_view::npos) nl = text.size();
    const std::string_view line = trim(text.substr(pos, nl - pos));
    pos = nl + 1;
    ++lineNo;
    if (line.empty() || line[0] == '#') continue;
    const auto eq = line.find('=');
    const std::string at = where + ":" + std::to_string(lineNo) + ": ";
    if (eq == std::string_view::npos) throw InputError(at + "expected 'key = value'");
    const std::string key(trim(line.substr(0, eq)));
    const std::string value(trim(line.substr(eq + 1)));
    if (key.empty()) throw InputError(at + "empty key");
    if (key.rfind("file.", 0) == 0) {
      DatasetFile f;
      f.key = key.substr(5);
      const auto w = words(value);
      if (w.size() != 3 || !parseNumber(w[1], f.size))
        throw InputError(at + "expected 'file.KEY = NAME BYTES CHECKSUM'");
      f.name = std::string(w[0]);
      if (!isPlainFileName(f.name))
        throw InputError(at + "file name '" + f.name + "' is not plain");
      if (w[2] != "-") {
        std::uint64_t c = 0;
        if (!parseNumber(w[2], c, 16))
          throw InputError(at + "bad checksum '" + std::string(w[2]) + "'");
        f.checksum = c;
      }
      if (!fileKeys.insert(f.key).second) throw InputError(at + "duplicate key '" + key + "'");
      files.push_back(std::move(f));
      continue;
    }
    if (!values.emplace(key, std::make_pair(value, lineNo)).second)
      throw InputError(at + "duplicate key '" + key + "'");
  }

  auto take = [&](const char* key) -> std::pair<std::string, std::string> {
    auto it = values.find(key);
    if (it == values.end()) throw InputError(where + ": missing key '" + key + "'");
    std::string v = it->second.first;
    std::string at = where + ":" + std::to_string(it->second.second) + ": ";
    values.erase(it);
    return {v, at};
  };
  auto takeU64 = [&](const char* key) {
    auto [v, at] = take(key);
    std::uint64_t n = 0;
    if (!parseNumber(std::string_view(v), n))
      throw InputError(at + key + ": expected an unsigned integer, got '" + v + "'");
    return n;
  };
  auto takeU32 = [&](const char* key) {
    const std::uint64_t n = takeU64(key);
    if (n > 0xffffffffull) throw InputError(where + ": " + key + " out of range");
    return static_cast<std::uint32_t>(n);
  };
  auto takeVec = [&](const char* key, float* out) {
    auto [v, at] = take(key);
    const auto w = words(v);
    if (w.size() != 3) throw InputError(at + key + ": expected three numbers");
    for (std::size_t i = 0; i < 3; ++i)
      if (!parseNumber(w[i], out[i]) || !std::isfinite(out[i]))
        throw InputError(at + key + ": bad number '" + std::string(w[i]) + "'");
  };

  DatasetManifest m;
  {
    auto [format, at] = take("format");
    if (format != kFormatName)
      throw InputError(at + "format is '" + format + "', expected '" + kFormatName + "'");
  }
  m.formatVersion = takeU32("format_version");
  if (m.formatVersion != kDatasetFormatVersion)
    throw InputError(where + ": unsupported format version " + std::to_string(m.formatVersion) +
                     " (this build reads version " + std::to_string(kDatasetFormatVersion) +
                     "; run pointillist-preprocess again)");
  m.createdBy = take("created_by").first;
  m.source = take("source").first;
  {
    auto [order, at] = take("byte_order");
    if (order != "little") throw InputError(at + "byte_order '" + order + "' is not supported");
  }
  m.recordSize = takeU32("record_size");
  m.cellSize = takeU32("cell_size");
  m.topLevelEntrySize = takeU32("top_level_entry_size");
  if (m.recordSize != sizeof(Splat) || m.cellSize != sizeof(OctreeCell) ||
      m.topLevelEntrySize != sizeof(TopLevelCell))
    throw InputError(where + ": record sizes " + std::to_string(m.recordSize) + "/" +
                     std::to_string(m.cellSize) + "/" + std::to_string(m.topLevelEntrySize) +
                     " do not match this build's 32/64/32 bytes");
  {
    auto [layout, at] = take("record_layout");
    if (layout != kRecordLayout) throw InputError(at + "unknown record layout '" + layout + "'");
  }
  takeVec("bounds_min", m.boundsMin);
  takeVec("bounds_max", m.boundsMax);
  m.pointCount = takeU64("point_count");
  m.levelSplatCount = takeU64("level_splat_count");
  m.cellCount = takeU64("cell_count");
  m.topLevelCount = takeU64("top_level_count");
  m.topLevelDepth = takeU32("top_level_depth");
  m.treeDepth = takeU32("tree_depth");
  m.maxLevel = takeU32("max_level");
  m.maxDepth = takeU32("max_depth");
  m.leafPoints = takeU32("leaf_points");
  {
    auto [v, at] = take("level_splat_reduction");
    if (!parseNumber(std::string_view(v), m.levelSplatReduction))
      throw InputError(at + "level_splat_reduction: bad number '" + v + "'");
  }
  {
    auto [algo, at] = take("checksum");
    if (algo != "fnv1a64") throw InputError(at + "unknown checksum algorithm '" + algo + "'");
  }
  for (auto& [k, v] : values) m.extra.emplace(k, v.first);
  m.files = std::move(files);
  for (const FileSpec& spec : {kCellsFile, kTopLevelFile, kChecksumsFile, kPointsFile})
    if (!m.file(spec.key)) throw InputError(where + ": missing key 'file." + spec.key + "'");
  return m;
}

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
  std::uint64_t offset = 0, points = 0, splats = 0;
  for (std::size_t k = 0; k < topLevel.size(); ++k) {
    const TopLevelCell& t = topLevel[k];
    const std::string at = tlWhere + ": entry " + std::to_string(k) + ": ";
    if (t.pointCount == 0) throw InputError(at + "no points");
    if (t.byteOffset != offset)
      throw InputError(at + "byte offset " + std::to_string(t.byteOffset) + ", expected " +
                       std::to_string(offset) + " (packets must be contiguous)");
    const std::uint64_t size = (std::uint64_t{t.pointCount} + t.levelSplatCount) * sizeof(Splat);
    if (t.byteSize != size)
      throw InputError(at + "byte size " + std::to_string(t.byteSize) + " does not match its " +
                       std::to_string(t.pointCount) + " points and " +
                       std::to_string(t.levelSplatCount) + " level-splats");
    if (k > 0 && t.cellIndex <= topLevel[k - 1].cellIndex)
      throw InputError(at + "cell index not increasing");
    if (t.cellIndex >= m.cellCount)
      throw InputError(at + "cell index " + std::to_string(t.cellIndex) + " out of range");
    offset += size;
    points += t.pointCount;
    splats += t.levelSplatCount;
  }
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
      if (c.pointsOffset != 0 || c.pointsCount != t.pointCount)
        fail(i, "top-level cell's points range is not its whole point part");
    } else if (p == kNoIndex || cells[p].topLevel != c.topLevel) {
      fail(i, "topLevel differs from its parent's");
    }
    const std::uint64_t P = t.pointCount, L = t.levelSplatCount;
    if (c.pointsCount == 0) fail(i, "empty cell");
    if (std::uint64_t{c.pointsOffset} + c.pointsCount > P)
      fail(i, "points range outside its packet");
    if (c.splatsCount != 0 &&
        (c.splatsOffset < P || std::uint64_t{c.splatsOffset} + c.splatsCount > P + L))
      fail(i, "level-splat range outside its packet's level-splats");
    if (children[i] == 0) {
      if (c.pointsOffset != leafRun[c.topLevel])
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
  for (std::size_t k = 0; k < topLevel.size(); ++k)
    if (leafRun[k] != topLevel[k].pointCount)
      throw InputError(tlWhere + ": entry " + std::to_string(k) + ": its leaves hold " +
                       std::to_string(leafRun[k]) + " of its " +
                       std::to_string(topLevel[k].pointCount) + " points");
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
  expectSize(kCellsFile, m.cellCount * sizeof(OctreeCell));
  expectSize(kTopLevelFile, m.topLevelCount * sizeof(TopLevelCell));
  expectSize(kChecksumsFile, m.topLevelCount * sizeof(std::uint64_t));
  expectSize(kPointsFile, (m.pointCount + m.levelSplatCount) * sizeof(Splat));

  auto loadChecked = [&](const FileSpec& spec) {
    const DatasetFile* f = m.file(spec.key);
    const fs::path p = dir / f->name;
    auto bytes = readWholeFile(p, f->size);
    const std::uint64_t sum = fnv1a64(bytes.data(), bytes.size());
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
  if (hasParts(parts, DatasetParts::TopLevel))
    validateDatasetStructure(m, ds.cells_, ds.topLevel_, dir.string());
  if (hasParts(parts, DatasetParts::Points)) {
    const DatasetFile* f = m.file(kPointsFile.key);
    const fs::path p = dir / f->name;
    ds.points_ = asRecords<Splat>(readWholeFile(p, f->size));
    for (std::uint32_t k = 0; k < ds.topLevel_.size(); ++k) {
      const auto s = ds.packet(k);
      const std::uint64_t sum = fnv1a64(s.data(), s.size_bytes());
      if (sum != ds.packetChecksums_[k])
        throw InputError(p.string() + ": top-level cell " + std::to_string(k) + " (bytes " +
                         std::to_string(ds.topLevel_[k].byteOffset) + "+" +
                         std::to_string(ds.topLevel_[k].byteSize) +
                         "): checksum mismatch (damaged file)");
    }
  }
  return ds;
}

std::uint64_t Dataset::packetChecksum(std::uint32_t topLevel) const {
  if (topLevel >= packetChecksums_.size())
    throw UsageError("top-level cell " + std::to_string(topLevel) +
                     " out of range or table not loaded");
  return packetChecksums_[topLevel];
}

std::span<const Splat> Dataset::packet(std::uint32_t topLevel) const {
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
  if (f->checksum && fnv1a64(bytes.data(), bytes.size()) != *f->checksum)
    throw InputError(p.string() + ": checksum mismatch (damaged file)");
  std::vector<std::byte> out(bytes.size());
  if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size());
  return out;
}

std::vector<Splat> Dataset::readTopLevel(std::uint32_t topLevel) const {
  if (topLevel >= topLevel_.size())
    throw UsageError("top-level cell " + std::to_string(topLevel) +
                     " out of range or table not loaded");
  const TopLevelCell& t = topLevel_[topLevel];
  const fs::path p = dir_ / manifest_.file(kPointsFile.key)->name;
  std::ifstream in(p, std::ios::binary);
  if (!in) throw InputError(p.string() + ": cannot open: " + std::strerror(errno));
  std::vector<Splat> out(static_cast<std::size_t>(t.byteSize / sizeof(Splat)));
  in.seekg(static_cast<std::streamoff>(t.byteOffset));
  in.read(reinterpret_cast<char*>(out.data()), static_cast<std::streamsize>(t.byteSize));
  if (!in || static_cast<std::uint64_t>(in.gcount()) != t.byteSize)
    throw InputError(p.string() + ": top-level cell " + std::to_string(topLevel) +
                     ": short read (truncated file)");
  const std::uint64_t sum = fnv1a64(out.data(), out.size() * sizeof(Splat));
  if (sum != packetChecksums_[topLevel])
    throw InputError(p.string() + ": top-level cell " + std::to_string(topLevel) + " (bytes " +
                     std::to_string(t.byteOffset) + "+" + std::to_string(t.byteSize) +
                     "): checksum mismatch (damaged file)");
  return out;
}

// ---------------------------------------------------------------- writing

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
    if (hashing_) hash_ = fnv1a64(data, size, hash_);
    size_ += size;
  }
  DatasetFile finish(const char* key) {
    out_.close();
    if (!out_) throw Error("cannot write " + path_.string() + ": " + std::strerror(errno));
    DatasetFile f{key, path_.filename().string(), size_, std::nullopt};
    if (hashing_) f.checksum = hash_;
    return f;
  }

 private:
  fs::path path_;
  std::ofstream out_;
  bool hashing_;
  std::uint64_t hash_ = kFnv1a64Offset;
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
  if (content.cells.empty() || content.topLevel.empty() || content.points.empty())
    throw Error("refusing to write an empty dataset");
  m.formatVersion = kDatasetFormatVersion;
  m.recordSize = sizeof(Splat);
  m.cellSize = sizeof(OctreeCell);
  m.topLevelEntrySize = sizeof(TopLevelCell);
  m.pointCount = content.points.size();
  m.levelSplatCount = content.levelSplats.size();
  m.cellCount = content.cells.size();
  m.topLevelCount = content.topLevel.size();
  m.maxLevel = content.cells[0].level;
  m.treeDepth = 0;
  for (const auto& c : content.cells) m.treeDepth = std::max<std::uint32_t>(m.treeDepth, c.depth);
  for (int a = 0; a < 3; ++a) {
    m.boundsMin[a] = content.cells[0].boundsMin[a];
    m.boundsMax[a] = content.cells[0].boundsMax[a];
  }
  std::uint64_t offset = 0;
  for (auto& t : content.topLevel) {
    t.byteOffset = offset;
    t.byteSize = (std::uint64_t{t.pointCount} + t.levelSplatCount) * sizeof(Splat);
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

std::uint64_t writeDataset(const fs::path& dirIn, DatasetContent& content, bool overwrite,
                           const DatasetProgressFn& progress) {
  fs::path dir = dirIn.lexically_normal();
  if (dir.filename().empty() && dir.has_parent_path()) dir = dir.parent_path();  // "ds/"
  if (dir.filename().empty() || dir.filename() == "." || dir.filename() == "..")
    throw UsageError("output " + quoted(dirIn) + " has no directory name");
  std::error_code ec;
  const bool exists = fs::exists(fs::symlink_status(dir, ec));
  if (exists && !overwrite) throw UsageError("output " + quoted(dir) + " already exists");
  if (exists && !looksLikeDataset(dir))
    throw UsageError("refusing to replace " + quoted(dir) + ": it is not a Pointillist dataset");

  finalizeDatasetContent(content);
  DatasetManifest& m = content.manifest;
  const std::uint64_t pointsBytes = m.file(kPointsFile.key)->size;

  if (!dir.parent_path().empty()) fs::create_directories(dir.parent_path(), ec);
  TempDir tmp(makeUniqueDir(dir, ".tmp-"));
  const std::uint64_t total = pointsBytes + m.cellCount * sizeof(OctreeCell);
  std::uint64_t done = 0;
  auto report = [&] {
    if (progress) progress(done, total);
  };

  std::vector<DatasetFile> files;
  {
    HashingWriter w(tmp.path() / kCellsFile.name);
    w.write(content.cells.data(), content.cells.size() * sizeof(OctreeCell));
    files.push_back(w.finish(kCellsFile.key));
    done += files.back().size;
    report();
  }
  std::vector<std::uint64_t> packetSums(content.topLevel.size());
  {
    // No whole-file hash: the packet checksums cover points.bin.
    HashingWriter w(tmp.path() / kPointsFile.name, false);
    std::size_t p = 0, s = 0;
    for (std::size_t k = 0; k < content.topLevel.size(); ++k) {
      const TopLevelCell& t = content.topLevel[k];
      const auto* pts = content.points.data() + p;
      const auto* lvl = content.levelSplats.data() + s;
      w.write(pts, t.pointCount * sizeof(Splat));
      w.write(lvl, t.levelSplatCount * sizeof(Splat));
      packetSums[k] = fnv1a64(lvl, t.levelSplatCount * sizeof(Splat),
                              fnv1a64(pts, t.pointCount * sizeof(Splat)));
      p += t.pointCount;
      s += t.levelSplatCount;
      done += t.byteSize;
      if ((k & 63) == 0) report();
    }
    files.push_back(w.finish(kPointsFile.key));
  }
  {
    HashingWriter w(tmp.path() / kTopLevelFile.name);
    w.write(content.topLevel.data(), content.topLevel.size() * sizeof(TopLevelCell));
    files.push_back(w.finish(kTopLevelFile.key));
  }
  {
    HashingWriter w(tmp.path() / kChecksumsFile.name);
    w.write(packetSums.data(), packetSums.size() * sizeof(std::uint64_t));
    files.push_back(w.finish(kChecksumsFile.key));
  }
  for (const auto& x : content.extraFiles) {
    if (!isPlainFileName(x.name) || x.name == kManifestName || x.key.empty() ||
        x.key.find_first_of(" \t=") != std::string::npos)
      throw Error("bad extra dataset file '" + x.key + "' -> '" + x.name + "'");
    for (const auto& f : files)
      if (f.key == x.key || f.name == x.name) throw Error("duplicate dataset file '" + x.key + "'");
    HashingWriter w(tmp.path() / x.name);
    w.write(x.bytes.data(), x.bytes.size());
    files.push_back(w.finish(x.key.c_str()));
  }
  m.files = std::move(files);
  std::uint64_t bytes = 0;
  for (const auto& f : m.files) bytes += f.size;
  {
    const std::string text = m.toText();
    bytes += text.size();
    std::ofstream out(tmp.path() / kManifestName, std::ios::binary | std::ios::trunc);
    out << text;
    out.close();
    if (!out) throw Error("cannot write " + (tmp.path() / kManifestName).string());
  }
  report();

  // Swap into place: the old dataset (if replacing) moves aside first.
  if (exists) {
    const fs::path old = makeUniqueDir(dir, ".old-");
    fs::rename(dir, old, ec);  // replaces the empty placeholder
    if (ec) {
      fs::remove(old);
      throw Error("cannot move " + quoted(dir) + " aside: " + ec.message());
    }
    fs::rename(tmp.path(), dir, ec);
    if (ec) {
      std::error_code ec2;
      fs::rename(old, dir, ec2);
      throw Error("cannot rename " + quoted(tmp.path()) + " to " + quoted(dir) + ": " +
                  ec.message());
    }
    fs::remove_all(old, ec);
  } else {
    fs::rename(tmp.path(), dir, ec);
    if (ec)
      throw Error("cannot rename " + quoted(tmp.path()) + " to " + quoted(dir) + ": " +
                  ec.message());
  }
  tmp.release();
  return bytes;
}

}  // namespace pointillist
