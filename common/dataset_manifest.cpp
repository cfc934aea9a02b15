// manifest.txt: writing and parsing the text, and the helpers the dataset's
// reader and writer share with it.
#include "common/dataset_manifest.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <set>
#include <sstream>
#include <system_error>
#include <type_traits>

#include "common/dataset_internal.hpp"
#include "common/errors.hpp"

namespace pointillist {

namespace dataset_detail {

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

bool isPlainFileName(std::string_view name) {
  return !name.empty() && name != "." && name != ".." && name.find('/') == std::string_view::npos &&
         name.find('\\') == std::string_view::npos;
}

std::string quoted(const std::filesystem::path& p) {
  std::string s = p.string();
  s.insert(s.begin(), '\'');
  s.push_back('\'');
  return s;
}

}  // namespace dataset_detail

using dataset_detail::FileSpec;
using dataset_detail::floatText;
using dataset_detail::hex64;
using dataset_detail::isPlainFileName;
using dataset_detail::kCellsFile;
using dataset_detail::kChecksumsFile;
using dataset_detail::kFormatName;
using dataset_detail::kPointsFile;
using dataset_detail::kTopLevelFile;
using dataset_detail::trim;

namespace {

constexpr const char* kRecordLayout = "position:f32x3 normal:f32x3 radius:f32 color:u8x4";

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

std::string oneLine(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  std::replace(s.begin(), s.end(), '\r', ' ');
  return s;
}

}  // namespace

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
  o << "max_splat_radius = " << floatText(maxSplatRadius) << "\n";
  o << "point_count = " << pointCount << "\n";
  o << "level_splat_count = " << levelSplatCount << "\n";
  if (instancedRecordCount > 0) o << "instanced_record_count = " << instancedRecordCount << "\n";
  o << "cell_count = " << cellCount << "\n";
  o << "top_level_count = " << topLevelCount << "\n";
  o << "top_level_depth = " << topLevelDepth << "\n";
  o << "tree_depth = " << treeDepth << "\n";
  o << "max_level = " << maxLevel << "\n";
  o << "max_depth = " << maxDepth << "\n";
  o << "leaf_points = " << leafPoints << "\n";
  o << "level_splat_reduction = " << levelSplatReduction << "\n";
  o << "checksum = " << kChecksumName << "\n";
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
  if (m.formatVersion != kDatasetFormatVersion) {
    const std::string written = m.formatVersion < kDatasetFormatVersion
                                    ? "an older pointillist-preprocess"
                                    : "a newer pointillist-preprocess";
    throw InputError(where + ": unsupported format version " + std::to_string(m.formatVersion) +
                     " (written by " + written + "; this build reads version " +
                     std::to_string(kDatasetFormatVersion) +
                     "): run pointillist-preprocess again to rebuild this dataset");
  }
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
  {
    auto [v, at] = take("max_splat_radius");
    if (!parseNumber(std::string_view(v), m.maxSplatRadius) || !std::isfinite(m.maxSplatRadius) ||
        m.maxSplatRadius < 0.0f)
      throw InputError(at + "max_splat_radius: expected a finite number >= 0, got '" + v + "'");
  }
  m.pointCount = takeU64("point_count");
  m.levelSplatCount = takeU64("level_splat_count");
  if (values.count("instanced_record_count") != 0)
    m.instancedRecordCount = takeU64("instanced_record_count");
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
    if (algo != kChecksumName) throw InputError(at + "unknown checksum algorithm '" + algo + "'");
  }
  for (auto& [k, v] : values) m.extra.emplace(k, v.first);
  m.files = std::move(files);
  for (const FileSpec& spec : {kCellsFile, kTopLevelFile, kChecksumsFile, kPointsFile})
    if (!m.file(spec.key)) throw InputError(where + ": missing key 'file." + spec.key + "'");
  return m;
}

}  // namespace pointillist
