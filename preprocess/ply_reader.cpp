#include "preprocess/ply_reader.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <iostream>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "preprocess/mesh_sampler.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/reader_toolkit.hpp"

namespace pointillist::preprocess {
namespace {

using detail::failAtByte;
using detail::failAtLine;
using detail::failFile;

enum class ScalarType : std::uint8_t {
  Int8,
  UInt8,
  Int16,
  UInt16,
  Int32,
  UInt32,
  Float32,
  Float64
};

bool parseType(std::string_view name, ScalarType& type) {
  struct Alias {
    std::string_view name;
    ScalarType type;
  };
  static constexpr Alias kAliases[] = {
      {"char", ScalarType::Int8},      {"int8", ScalarType::Int8},
      {"uchar", ScalarType::UInt8},    {"uint8", ScalarType::UInt8},
      {"short", ScalarType::Int16},    {"int16", ScalarType::Int16},
      {"ushort", ScalarType::UInt16},  {"uint16", ScalarType::UInt16},
      {"int", ScalarType::Int32},      {"int32", ScalarType::Int32},
      {"uint", ScalarType::UInt32},    {"uint32", ScalarType::UInt32},
      {"float", ScalarType::Float32},  {"float32", ScalarType::Float32},
      {"double", ScalarType::Float64}, {"float64", ScalarType::Float64},
  };
  for (const Alias& alias : kAliases) {
    if (alias.name == name) {
      type = alias.type;
      return true;
    }
  }
  return false;
}

std::size_t typeSize(ScalarType type) {
  switch (type) {
    case ScalarType::Int8:
    case ScalarType::UInt8:
      return 1;
    case ScalarType::Int16:
    case ScalarType::UInt16:
      return 2;
    case ScalarType::Int32:
    case ScalarType::UInt32:
    case ScalarType::Float32:
      return 4;
    case ScalarType::Float64:
      return 8;
  }
  return 0;
}

bool isFloat(ScalarType type) {
  return type == ScalarType::Float32 || type == ScalarType::Float64;
}

enum class Role : std::uint8_t {
  None,
  X,
  Y,
  Z,
  NX,
  NY,
  NZ,
  Red,
  Green,
  Blue,
  Alpha,
  Radius,
  Indices
};
constexpr std::size_t kRoles = 13;

Role vertexRole(std::string_view name) {
  if (name == "x") return Role::X;
  if (name == "y") return Role::Y;
  if (name == "z") return Role::Z;
  if (name == "nx" || name == "normal_x") return Role::NX;
  if (name == "ny" || name == "normal_y") return Role::NY;
  if (name == "nz" || name == "normal_z") return Role::NZ;
  if (name == "red" || name == "r" || name == "diffuse_red") return Role::Red;
  if (name == "green" || name == "g" || name == "diffuse_green") return Role::Green;
  if (name == "blue" || name == "b" || name == "diffuse_blue") return Role::Blue;
  if (name == "alpha" || name == "a") return Role::Alpha;
  if (name == "radius") return Role::Radius;
  return Role::None;
}

Role faceRole(std::string_view name) {
  if (name == "vertex_indices" || name == "vertex_index") return Role::Indices;
  if (name == "red") return Role::Red;
  if (name == "green") return Role::Green;
  if (name == "blue") return Role::Blue;
  if (name == "alpha") return Role::Alpha;
  return Role::None;
}

struct Property {
  std::string name;
  ScalarType type = ScalarType::Float32;
  bool isList = false;
  ScalarType countType = ScalarType::UInt8;
  Role role = Role::None;
  std::size_t offset = 0;  // within a fixed-size binary record
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::uint64_t headerLine = 0;
  std::vector<Property> properties;
  bool fixedSize = true;
  std::size_t recordSize = 0;   // bytes per binary record when fixedSize
  std::size_t minSize = 0;      // lower bound on bytes per binary record
  std::vector<Property> known;  // the properties with a role, for the fast paths
};

enum class Format { Ascii, BinaryLittle, BinaryBig };

std::string plural(const Element& element) {
  if (element.name == "vertex") return "vertices";
  if (element.name == "face") return "faces";
  return "'" + element.name + "' elements";
}

// Colour channel from its stored value: integers are 0..255 (16-bit ones are
// scaled down), floats are 0..1.
std::uint8_t colorChannel(double value, ScalarType type) {
  if (isFloat(type)) return detail::colorFromUnit(value);
  if (type == ScalarType::UInt16 || type == ScalarType::Int16) value /= 257.0;
  return detail::colorFromByte(value);
}

class PlyParser {
 public:
  PlyParser(const std::filesystem::path& file, const ReadOptions& options)
      : file_(file), options_(options), reader_(file), builder_(file, options) {}

  PointCloud run() {
    parseHeader();
    for (Element& element : elements_) {
      if (&element == vertex_) {
        readElement(element, Kind::Vertex);
      } else if (&element == face_) {
        readElement(element, Kind::Face);
      } else {
        readElement(element, Kind::Skip);
      }
    }
    checkTrailingData();
    builder_.progress(reader_.size(), reader_.size());
    if (!isMesh_) return builder_.finish(hasNormals_, hasColors_, hasRadius_);
    return finishMesh();
  }

 private:
  enum class Kind { Vertex, Face, Skip };

  void parseHeader() {
    std::string_view line;
    std::vector<std::string_view> f;
    if (!reader_.readLine(line) || line != "ply") {
      failAtLine(file_, 1, "not a PLY file (the first line must be 'ply')");
    }
    bool sawFormat = false;
    Element* current = nullptr;
    for (;;) {
      if (!reader_.readLine(line)) {
        failAtLine(file_, reader_.lineNumber(), "header has no end_header line (truncated file?)");
      }
      const std::uint64_t at = reader_.lineNumber();
      detail::splitFields(line, f);
      if (f.empty()) continue;
      if (f[0] == "end_header") break;
      if (f[0] == "comment" || f[0] == "obj_info") continue;
      if (f[0] == "format") {
        if (f.size() != 3) failAtLine(file_, at, "malformed format line");
        if (f[1] == "ascii") {
          format_ = Format::Ascii;
        } else if (f[1] == "binary_little_endian") {
          format_ = Format::BinaryLittle;
        } else if (f[1] == "binary_big_endian") {
          format_ = Format::BinaryBig;
        } else {
          failAtLine(file_, at, "unknown PLY format '" + std::string(f[1]) + "'");
        }
        if (f[2] != "1.0") failAtLine(file_, at, "unsupported PLY version " + std::string(f[2]));
        sawFormat = true;
      } else if (f[0] == "element") {
        Element element;
        if (f.size() != 3 || !detail::parseUnsigned(f[2], element.count)) {
          failAtLine(file_, at, "malformed element line (expected 'element <name> <count>')");
        }
        element.name = std::string(f[1]);
        element.headerLine = at;
        elements_.push_back(std::move(element));
        current = &elements_.back();
      } else if (f[0] == "property") {
        if (current == nullptr) failAtLine(file_, at, "property before any element");
        Property property;
        bool ok = false;
        if (f.size() == 3) {
          ok = parseType(f[1], property.type);
          property.name = std::string(f[2]);
        } else if (f.size() == 5 && f[1] == "list") {
          property.isList = true;
          ok = parseType(f[2], property.countType) && parseType(f[3], property.type) &&
               !isFloat(property.countType);
          property.name = std::string(f[4]);
        }
        if (!ok) failAtLine(file_, at, "malformed or unknown property type: " + std::string(line));
        current->properties.push_back(std::move(property));
      } else {
        failAtLine(file_, at, "unexpected header line: " + std::string(line));
      }
    }
    const std::uint64_t endLine = reader_.lineNumber();
    if (!sawFormat) failAtLine(file_, endLine, "header has no format line");
    swap_ = (format_ == Format::BinaryLittle) != (std::endian::native == std::endian::little);

    for (Element& element : elements_) {
      for (Property& p : element.properties) {
        p.offset = element.recordSize;
        if (p.isList) {
          element.fixedSize = false;
          element.minSize += typeSize(p.countType);
        } else {
          element.recordSize += typeSize(p.type);
          element.minSize += typeSize(p.type);
        }
      }
      if (element.name == "vertex" && vertex_ == nullptr) vertex_ = &element;
      if (element.name == "face" && face_ == nullptr) face_ = &element;
    }
    if (vertex_ == nullptr) failAtLine(file_, endLine, "no 'vertex' element in the header");

    bool seen[kRoles] = {};
    for (Property& p : vertex_->properties) {
      p.role = vertexRole(p.name);
      if (p.role != Role::None && p.isList) {
        failAtLine(file_, vertex_->headerLine, "vertex property '" + p.name + "' is a list");
      }
      seen[static_cast<std::size_t>(p.role)] = true;
    }
    if (!seen[static_cast<std::size_t>(Role::X)] || !seen[static_cast<std::size_t>(Role::Y)] ||
        !seen[static_cast<std::size_t>(Role::Z)]) {
      failAtLine(file_, vertex_->headerLine, "vertex element lacks x, y or z");
    }
    hasNormals_ = seen[static_cast<std::size_t>(Role::NX)] &&
                  seen[static_cast<std::size_t>(Role::NY)] &&
                  seen[static_cast<std::size_t>(Role::NZ)];
    hasColors_ = seen[static_cast<std::size_t>(Role::Red)] &&
                 seen[static_cast<std::size_t>(Role::Green)] &&
                 seen[static_cast<std::size_t>(Role::Blue)];
    hasRadius_ = seen[static_cast<std::size_t>(Role::Radius)];
    for (const Property& p : vertex_->properties) {
      if (p.role != Role::None) vertex_->known.push_back(p);
    }

    if (face_ != nullptr) {
      bool hasIndices = false;
      bool faceSeen[kRoles] = {};
      for (Property& p : face_->properties) {
        p.role = faceRole(p.name);
        if (p.role == Role::Indices && !p.isList) p.role = Role::None;
        if (p.role != Role::Indices && p.isList) p.role = Role::None;
        if (p.role == Role::Indices) {
          if (isFloat(p.type)) {
            failAtLine(file_, face_->headerLine, "face indices must have an integer type");
          }
          if (hasIndices) p.role = Role::None;  // only the first index list counts
          hasIndices = true;
        }
        faceSeen[static_cast<std::size_t>(p.role)] = true;
      }
      isMesh_ = hasIndices && face_->count > 0;
      for (const Property& p : face_->properties) {
        if (p.role != Role::None) face_->known.push_back(p);
      }
      faceColors_ = faceSeen[static_cast<std::size_t>(Role::Red)] &&
                    faceSeen[static_cast<std::size_t>(Role::Green)] &&
                    faceSeen[static_cast<std::size_t>(Role::Blue)];
    }
  }

  // The raw value of one scalar in a binary record.
  double decode(const unsigned char* p, ScalarType type) const {
    unsigned char b[8];
    const std::size_t n = typeSize(type);
    if (swap_) {
      for (std::size_t i = 0; i < n; ++i) b[i] = p[n - 1 - i];
    } else {
      std::memcpy(b, p, n);
    }
    switch (type) {
      case ScalarType::Int8: {
        std::int8_t v;
        std::memcpy(&v, b, 1);
        return v;
      }
      case ScalarType::UInt8:
        return b[0];
      case ScalarType::Int16: {
        std::int16_t v;
        std::memcpy(&v, b, 2);
        return v;
      }
      case ScalarType::UInt16: {
        std::uint16_t v;
        std::memcpy(&v, b, 2);
        return v;
      }
      case ScalarType::Int32: {
        std::int32_t v;
        std::memcpy(&v, b, 4);
        return v;
      }
      case ScalarType::UInt32: {
        std::uint32_t v;
        std::memcpy(&v, b, 4);
        return v;
      }
      case ScalarType::Float32: {
        float v;
        std::memcpy(&v, b, 4);
        return static_cast<double>(v);
      }
      case ScalarType::Float64: {
        double v;
        std::memcpy(&v, b, 8);
        return v;
      }
    }
    return 0.0;
  }

  // `at`: byte offset of the incomplete record (binary only).
  [[noreturn]] void truncated(const Element& element, std::uint64_t got, std::uint64_t at = 0) {
    const std::string message = "truncated " + element.name + " data (expected " +
                                std::to_string(element.count) + " " + plural(element) + ", got " +
                                std::to_string(got) + ")";
    if (format_ == Format::Ascii) failAtLine(file_, reader_.lineNumber(), message);
    failAtByte(file_, at != 0 ? at : reader_.offset(), message);
  }

  void readElement(const Element& element, Kind kind) {
    const bool binary = format_ != Format::Ascii;
    const std::uint64_t remaining = reader_.size() - std::min(reader_.size(), reader_.offset());
    if (kind == Kind::Vertex) {
      // The header count only sizes the reservation as far as the file can back it.
      const std::uint64_t limit =
          remaining / std::max<std::size_t>(1, binary ? element.minSize : 2);
      if (isMesh_) {
        mesh_.vertices.reserve(static_cast<std::size_t>(std::min(element.count, limit)));
      } else {
        builder_.reserve(element.count, limit);
      }
    }
    if (binary && kind == Kind::Skip && element.fixedSize) {
      const std::uint64_t bytes = element.count * element.recordSize;
      if (element.recordSize != 0 && element.count > remaining / element.recordSize) {
        const std::uint64_t whole = remaining / element.recordSize;
        truncated(element, whole, reader_.offset() + whole * element.recordSize);
      }
      reader_.skip(bytes);
      return;
    }
    if (binary && element.fixedSize && kind == Kind::Vertex && !isMesh_) {
      readVertexBlocks(element);
      return;
    }
    std::vector<unsigned char> record(element.recordSize);
    for (std::uint64_t i = 0; i < element.count; ++i) {
      values_.fill(0.0);
      indices_.clear();
      const std::uint64_t where = binary ? reader_.offset() : 0;
      if (binary) {
        if (element.fixedSize) {
          if (reader_.read(record.data(), record.size()) != record.size()) {
            truncated(element, i, where);
          }
          for (const Property& p : element.known) {
            values_[static_cast<std::size_t>(p.role)] = decode(record.data() + p.offset, p.type);
          }
        } else {
          readBinaryInstance(element, i, kind != Kind::Skip, where);
        }
      } else {
        readAsciiInstance(element, i);
      }
      const std::uint64_t line = binary ? 0 : reader_.lineNumber();
      if (kind == Kind::Vertex) {
        addVertex(element, line, where);
      } else if (kind == Kind::Face) {
        addFace(line, where);
      }
      if ((i & 4095) == 0) builder_.progress(reader_.offset(), reader_.size());
    }
  }

  void readBinaryInstance(const Element& element, std::uint64_t index, bool keep,
                          std::uint64_t start) {
    unsigned char b[8];
    for (const Property& p : element.properties) {
      if (!p.isList) {
        const std::size_t n = typeSize(p.type);
        if (reader_.read(b, n) != n) truncated(element, index, start);
        if (keep && p.role != Role::None)
          values_[static_cast<std::size_t>(p.role)] = decode(b, p.type);
        continue;
      }
      const std::uint64_t at = reader_.offset();
      const std::size_t countSize = typeSize(p.countType);
      if (reader_.read(b, countSize) != countSize) truncated(element, index, start);
      std::uint64_t n = 0;
      if (!detail::wholeCount(decode(b, p.countType), n)) {
        failAtByte(file_, at, "bad list length in " + element.name + " " + std::to_string(index));
      }
      const std::size_t itemSize = typeSize(p.type);
      // Compared by division: n * itemSize may wrap.
      if (n > reader_.size() / itemSize) truncated(element, index, start);
      if (!keep || p.role != Role::Indices) {
        if (reader_.skip(n * itemSize) != n * itemSize) truncated(element, index, start);
        continue;
      }
      for (std::uint64_t k = 0; k < n; ++k) {
        if (reader_.read(b, itemSize) != itemSize) truncated(element, index, start);
        indices_.push_back(decode(b, p.type));
      }
    }
  }

  void readAsciiInstance(const Element& element, std::uint64_t index) {
    std::string_view line;
    do {
      if (!reader_.readLine(line)) truncated(element, index);
      detail::splitFields(line, fields_);
    } while (fields_.empty());
    const std::uint64_t at = reader_.lineNumber();
    std::size_t next = 0;
    const auto take = [&](double& value) {
      if (next >= fields_.size()) {
        failAtLine(file_, at,
                   "too few values for " + element.name + " " + std::to_string(index) +
                       " (the header declares more properties)");
      }
      const std::string_view field = fields_[next++];
      if (!detail::parseDouble(field, value)) {
        failAtLine(file_, at, "not a number: '" + std::string(field) + "'");
      }
    };
    for (const Property& p : element.properties) {
      double value = 0.0;
      if (!p.isList) {
        take(value);
        if (p.role != Role::None) values_[static_cast<std::size_t>(p.role)] = value;
        continue;
      }
      take(value);
      std::uint64_t n = 0;
      if (!detail::wholeCount(value, n)) {
        failAtLine(file_, at, "bad list length in " + element.name + " " + std::to_string(index));
      }
      for (std::uint64_t k = 0; k < n; ++k) {
        take(value);
        if (p.role == Role::Indices) indices_.push_back(value);
      }
    }
    if (next != fields_.size()) {
      failAtLine(file_, at,
                 "more values than the header declares for " + element.name + " " +
                     std::to_string(index) + " (" + std::to_string(fields_.size()) +
                     " instead of " + std::to_string(next) + ")");
    }
  }

  using Values = std::array<double, kRoles>;

  double value(Role role) const { return values_[static_cast<std::size_t>(role)]; }

  std::array<std::uint8_t, 4> colorOf(const Element& element) const {
    return colorOf(element, values_);
  }
  static std::array<std::uint8_t, 4> colorOf(const Element& element, const Values& v) {
    std::array<std::uint8_t, 4> c{kDefaultGrey, kDefaultGrey, kDefaultGrey, 255};
    for (const Property& p : element.known) {
      const std::size_t slot = p.role == Role::Red     ? 0
                               : p.role == Role::Green ? 1
                               : p.role == Role::Blue  ? 2
                               : p.role == Role::Alpha ? 3
                                                       : 4;
      if (slot < 4) c[slot] = colorChannel(v[static_cast<std::size_t>(p.role)], p.type);
    }
    return c;
  }

  // A point vertex (not a mesh's) from its property values.
  Splat vertexSplat(const Element& element, const Values& v) const {
    const auto at = [&v](Role r) { return v[static_cast<std::size_t>(r)]; };
    Splat s = detail::greySplat();
    s.position[0] = static_cast<float>(at(Role::X));
    s.position[1] = static_cast<float>(at(Role::Y));
    s.position[2] = static_cast<float>(at(Role::Z));
    if (hasNormals_) {
      s.normal[0] = static_cast<float>(at(Role::NX));
      s.normal[1] = static_cast<float>(at(Role::NY));
      s.normal[2] = static_cast<float>(at(Role::NZ));
    }
    if (hasRadius_) s.radius = static_cast<float>(at(Role::Radius));
    if (hasColors_) {
      const auto c = colorOf(element, v);
      std::copy(c.begin(), c.end(), s.color);
    }
    return s;
  }

  // Fixed-size binary point vertices: a block of records read at once and
  // decoded on every core; only the checks and the hand-over stay in order.
  void readVertexBlocks(const Element& element) {
    constexpr std::size_t kBlock = std::size_t{1} << 16;
    const std::size_t size = element.recordSize;
    std::vector<unsigned char> bytes(kBlock * size);
    std::vector<Splat> splats(kBlock);
    // Where each known property goes in the splat, decided once.
    struct Field {
      std::size_t offset;
      ScalarType type;
      int slot;  // 0-2 position, 3-5 normal, 6 radius, 7-10 colour
    };
    std::vector<Field> fields;
    for (const Property& p : element.known) {
      int slot = -1;
      switch (p.role) {
        case Role::X:
          slot = 0;
          break;
        case Role::Y:
          slot = 1;
          break;
        case Role::Z:
          slot = 2;
          break;
        case Role::NX:
          slot = hasNormals_ ? 3 : -1;
          break;
        case Role::NY:
          slot = hasNormals_ ? 4 : -1;
          break;
        case Role::NZ:
          slot = hasNormals_ ? 5 : -1;
          break;
        case Role::Radius:
          slot = hasRadius_ ? 6 : -1;
          break;
        case Role::Red:
          slot = hasColors_ ? 7 : -1;
          break;
        case Role::Green:
          slot = hasColors_ ? 8 : -1;
          break;
        case Role::Blue:
          slot = hasColors_ ? 9 : -1;
          break;
        case Role::Alpha:
          slot = hasColors_ ? 10 : -1;
          break;
        default:
          break;
      }
      if (slot >= 0) fields.push_back({p.offset, p.type, slot});
    }
    // The common layout (little-endian floats, byte colours) by fixed offsets;
    // anything else by the general loop. Both fill a splat on the stack,
    // which is stored once.
    std::array<int, 11> offsetOf{};
    offsetOf.fill(-1);
    for (const Field& f : fields)
      offsetOf[static_cast<std::size_t>(f.slot)] = static_cast<int>(f.offset);
    const bool plain = offsetOf[0] >= 0 && offsetOf[1] >= 0 && offsetOf[2] >= 0 &&
                       std::all_of(fields.begin(), fields.end(), [&](const Field& f) {
                         return f.slot >= 7 ? f.type == ScalarType::UInt8
                                            : f.type == ScalarType::Float32 && !swap_;
                       });
    const bool plainNormals = offsetOf[3] >= 0 && offsetOf[4] >= 0 && offsetOf[5] >= 0;
    const Splat grey = detail::greySplat();
    const auto decodeRecord = [&](const unsigned char* record) {
      Splat out = grey;
      if (plain) {
        for (std::size_t a = 0; a < 3; ++a)
          std::memcpy(&out.position[a], record + offsetOf[a], sizeof(float));
        if (plainNormals)
          for (std::size_t a = 0; a < 3; ++a)
            std::memcpy(&out.normal[a], record + offsetOf[3 + a], sizeof(float));
        if (offsetOf[6] >= 0) std::memcpy(&out.radius, record + offsetOf[6], sizeof(float));
        for (std::size_t c = 0; c < 4; ++c)
          if (offsetOf[7 + c] >= 0) out.color[c] = record[offsetOf[7 + c]];
        return out;
      }
      for (const Field& f : fields) {
        const unsigned char* at = record + f.offset;
        if (f.slot >= 7) {
          // Bytes are colours as they are; other types go through the scaling.
          out.color[f.slot - 7] =
              f.type == ScalarType::UInt8 ? *at : colorChannel(decode(at, f.type), f.type);
          continue;
        }
        float v;
        if (f.type == ScalarType::Float32 && !swap_)
          std::memcpy(&v, at, sizeof v);  // the common case, without the round trip
        else
          v = static_cast<float>(decode(at, f.type));
        if (f.slot < 3)
          out.position[f.slot] = v;
        else if (f.slot < 6)
          out.normal[f.slot - 3] = v;
        else
          out.radius = v;
      }
      return out;
    };
    // The next block is read while this one is decoded: the copy out of the
    // page cache would otherwise leave the other cores waiting.
    std::vector<unsigned char> next(kBlock * size);
    const auto blockAt = [&](std::uint64_t i) {
      return static_cast<std::size_t>(std::min<std::uint64_t>(kBlock, element.count - i));
    };
    std::uint64_t where = reader_.offset();
    std::size_t got = element.count > 0 ? reader_.read(bytes.data(), blockAt(0) * size) : 0;
    for (std::uint64_t i = 0; i < element.count;) {
      const std::size_t n = blockAt(i);
      if (got != n * size) truncated(element, i + got / size, where + got / size * size);
      const std::uint64_t nextWhere = reader_.offset();
      std::size_t nextGot = 0;
      std::exception_ptr readError;
      std::thread reading;
      if (i + n < element.count) {
        reading = std::thread([&, want = blockAt(i + n) * size] {
          try {
            nextGot = reader_.read(next.data(), want);
          } catch (...) {
            readError = std::current_exception();
          }
        });
      }
      // Decoded, prepared and checked on all threads, into the cloud itself
      // where it is held in memory (else into `splats`, handed over in one
      // copy). A block with a non-finite splat goes one by one, for the message.
      std::atomic<bool> anyNonFinite{false}, anyWithoutNormal{false};
      try {
        const std::span<Splat> room = builder_.appendRoom(n);
        Splat* const into = room.empty() ? splats.data() : room.data();
        parallelFor(
            n, 0,
            [&](std::size_t j) {
              Splat s = decodeRecord(bytes.data() + j * size);
              detail::CloudBuilder::prepare(s);
              if (!detail::isFinite(s)) anyNonFinite.store(true, std::memory_order_relaxed);
              if (!hasNormal(s)) anyWithoutNormal.store(true, std::memory_order_relaxed);
              into[j] = s;
            },
            4096);
        if (!anyNonFinite.load()) {
          if (room.empty())
            builder_.addPreparedFinite(std::span<const Splat>(splats).first(n),
                                       !anyWithoutNormal.load());
          else
            builder_.keepRoom(!anyWithoutNormal.load());
        } else {
          if (!room.empty()) {
            std::copy(room.begin(), room.end(), splats.begin());
            builder_.giveBackRoom();
          }
          for (std::size_t j = 0; j < n; ++j) builder_.addPrepared(splats[j], 0, where + j * size);
        }
      } catch (...) {
        if (reading.joinable()) reading.join();
        throw;
      }
      if (reading.joinable()) reading.join();
      if (readError) std::rethrow_exception(readError);
      i += n;
      builder_.progress(nextWhere, reader_.size());
      bytes.swap(next);
      where = nextWhere;
      got = nextGot;
    }
  }

  void addVertex(const Element& element, std::uint64_t line, std::uint64_t byte) {
    if (isMesh_) {
      const std::array<double, 3> v{value(Role::X), value(Role::Y), value(Role::Z)};
      const bool finite =
          detail::fitsFloat(v[0]) && detail::fitsFloat(v[1]) && detail::fitsFloat(v[2]);
      if (!finite) {
        const std::string message =
            "non-finite vertex coordinate (NaN or Inf) (pass --drop-non-finite to skip it)";
        if (!options_.dropNonFinite) {
          if (line > 0) failAtLine(file_, line, message);
          failAtByte(file_, byte, message);
        }
        badVertices_.resize(mesh_.vertices.size() + 1,
                            false);  // not the header count: absurd ones exist
        badVertices_.back() = true;
        ++droppedVertices_;
      }
      mesh_.vertices.push_back(v);
      if (hasColors_) mesh_.vertexColors.push_back(colorOf(element));
      return;
    }
    builder_.add(vertexSplat(element, values_), line, byte);
  }

  void addFace(std::uint64_t line, std::uint64_t byte) {
    if (!isMesh_) return;
    const std::uint64_t vertexCount = vertex_->count;
    std::uint32_t corners[3] = {};
    for (std::size_t k = 0; k < indices_.size(); ++k) {
      std::uint64_t whole = 0;
      if (!detail::wholeCount(indices_[k], whole) || whole >= vertexCount ||
          whole > std::numeric_limits<std::uint32_t>::max()) {
        char shown[32];
        std::snprintf(shown, sizeof shown, "%.17g", indices_[k]);
        const std::string message = std::string("face vertex index ") + shown +
                                    " out of range (the mesh has " + std::to_string(vertexCount) +
                                    " vertices)";
        if (line > 0) failAtLine(file_, line, message);
        failAtByte(file_, byte, message);
      }
      // Fan triangulation: (v0, v[k-1], v[k]).
      const auto i = static_cast<std::uint32_t>(whole);
      if (k == 0) {
        corners[0] = i;
      } else if (k == 1) {
        corners[1] = i;
      } else {
        corners[2] = i;
        mesh_.triangles.push_back({corners[0], corners[1], corners[2]});
        if (faceColors_) mesh_.triangleColors.push_back(colorOf(*face_));
        corners[1] = i;
      }
    }
  }

  void checkTrailingData() {
    if (format_ == Format::Ascii) {
      std::string_view line;
      while (reader_.readLine(line)) {
        detail::splitFields(line, fields_);
        if (!fields_.empty()) {
          failAtLine(file_, reader_.lineNumber(),
                     "more data than the header declares (element counts too small?)");
        }
      }
      return;
    }
    const std::uint64_t at = reader_.offset();
    char tail[64];
    const std::size_t n = reader_.read(tail, sizeof tail);
    const bool blank = std::all_of(
        tail, tail + n, [](char c) { return c == '\n' || c == '\r' || c == ' ' || c == '\0'; });
    if (n == sizeof tail || !blank) {
      failAtByte(file_, at,
                 std::to_string(reader_.size() - at) +
                     " bytes after the last element (element counts too small?)");
    }
  }

  PointCloud finishMesh() {
    if (droppedVertices_ > 0) {
      std::erase_if(mesh_.triangles, [this](const std::array<std::uint32_t, 3>& t) {
        const auto bad = [this](std::uint32_t v) {
          return v < badVertices_.size() && badVertices_[v];
        };
        return bad(t[0]) || bad(t[1]) || bad(t[2]);
      });
      std::cerr << "warning: " << file_.string() << ": dropped " << droppedVertices_
                << " vertices with NaN/Inf coordinates and the faces using them\n";
      mesh_.triangleColors.clear();  // no longer parallel to the triangles
    }
    if (mesh_.triangles.empty()) failFile(file_, "mesh has no usable faces");
    return sampleMesh(mesh_, options_.meshSamplePoints, options_.seed, file_.string());
  }

  const std::filesystem::path& file_;
  const ReadOptions& options_;
  detail::FileReader reader_;
  detail::CloudBuilder builder_;

  Format format_ = Format::Ascii;
  bool swap_ = false;
  std::vector<Element> elements_;
  Element* vertex_ = nullptr;
  Element* face_ = nullptr;
  bool hasNormals_ = false;
  bool hasColors_ = false;
  bool hasRadius_ = false;
  bool isMesh_ = false;
  bool faceColors_ = false;

  std::array<double, kRoles> values_{};
  std::vector<double> indices_;
  std::vector<std::string_view> fields_;

  TriangleMesh mesh_;
  std::vector<bool> badVertices_;
  std::uint64_t droppedVertices_ = 0;
};

}  // namespace

PointCloud readPly(const std::filesystem::path& file, const ReadOptions& options) {
  PlyParser parser(file, options);
  return parser.run();
}

}  // namespace pointillist::preprocess
