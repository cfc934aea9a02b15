#include "common/statistical_node.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <string>

#include "common/errors.hpp"

namespace pointillist {

namespace {

constexpr std::uint32_t kClassesMagic = 0x43535450u;  // "PTSC"
constexpr std::uint16_t kClassesVersion = 1;
constexpr double kPi = std::numbers::pi;

struct ClassesHeader {
  std::uint32_t magic;
  std::uint16_t version;
  std::uint16_t position;
  std::uint16_t normal;
  std::uint16_t color;
  std::uint32_t reserved;
};
static_assert(sizeof(ClassesHeader) == 16);

constexpr std::uint32_t kMeanBits[3] = {11, 11, 10};

// Little-endian bit stream over the node's 18 bytes.
class BitWriter {
 public:
  explicit BitWriter(std::byte* out) : out_(out) { std::memset(out, 0, kStatisticalNodeBytes); }
  void put(std::uint32_t value, std::uint32_t bits) {
    for (std::uint32_t b = 0; b < bits; ++b, ++bit_)
      if ((value >> b) & 1u)
        out_[bit_ >> 3] |= std::byte{static_cast<unsigned char>(1u << (bit_ & 7u))};
  }

 private:
  std::byte* out_;
  std::uint32_t bit_ = 0;
};

class BitReader {
 public:
  explicit BitReader(const std::byte* in) : in_(in) {}
  std::uint16_t get(std::uint32_t bits) {
    std::uint32_t value = 0;
    for (std::uint32_t b = 0; b < bits; ++b, ++bit_)
      value |= ((std::to_integer<std::uint32_t>(in_[bit_ >> 3]) >> (bit_ & 7u)) & 1u) << b;
    return static_cast<std::uint16_t>(value);
  }

 private:
  const std::byte* in_;
  std::uint32_t bit_ = 0;
};

struct FrameBits {
  std::uint32_t theta, phi, psi;
  double thetaMax;
  bool hemisphere;
};
FrameBits frameBits(FrameKind kind) {
  switch (kind) {
    case FrameKind::Position:
      return {8, 10, 6, kPi / 2, true};
    case FrameKind::Normal:
      return {8, 10, 6, kPi, false};
    case FrameKind::Color:
      return {4, 3, 3, kPi / 2, true};
  }
  return {8, 10, 6, kPi / 2, true};
}

using Axes = std::array<std::array<double, 3>, 3>;

double dot3(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
std::array<double, 3> cross3(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

// f3 from (theta, phi) and x', y': the x and y axes rotated like z onto f3
// (about z x f3 by theta, seed 004 §5), so psi = 0 gives f1 = x'.
void baseFrame(double theta, double phi, std::array<double, 3>& f3, std::array<double, 3>& x,
               std::array<double, 3>& y) {
  const double st = std::sin(theta), ct = std::cos(theta), sp = std::sin(phi), cp = std::cos(phi);
  f3 = {cp * st, sp * st, ct};
  x = {ct + sp * sp * (1 - ct), -sp * cp * (1 - ct), -cp * st};
  y = cross3(f3, x);
}

Axes frameFromAngles(double theta, double phi, double psi) {
  std::array<double, 3> f3, x, y;
  baseFrame(theta, phi, f3, x, y);
  const double c = std::cos(psi), s = std::sin(psi);
  std::array<double, 3> f1 = {c * x[0] + s * y[0], c * x[1] + s * y[1], c * x[2] + s * y[2]};
  return {f1, cross3(f3, f1), f3};
}

double codeAngle(std::uint32_t code, std::uint32_t bits, double range, bool closed) {
  // closed: codes 0 and 2^bits - 1 are both ends of [0, range]; else [0, range).
  const double steps = closed ? double((1u << bits) - 1) : double(1u << bits);
  return code * range / steps;
}

std::uint16_t angleCode(double angle, std::uint32_t bits, double range, bool closed) {
  const std::uint32_t n = 1u << bits;
  if (closed) {
    const double q = std::round(std::clamp(angle / range, 0.0, 1.0) * (n - 1));
    return static_cast<std::uint16_t>(q);
  }
  double a = std::fmod(angle, range);
  if (a < 0) a += range;
  return static_cast<std::uint16_t>(static_cast<std::uint32_t>(std::round(a / range * n)) % n);
}

template <std::size_t D>
void checkTable(const std::vector<std::array<float, D>>& table, const std::string& at,
                const char* name) {
  for (std::size_t i = 0; i < table.size(); ++i)
    for (float v : table[i])
      if (!std::isfinite(v) || v < 0.0f)
        throw InputError(at + name + " class " + std::to_string(i) + " is negative or not finite");
}

}  // namespace

void packStatisticalNode(const StatisticalNodeCode& c, std::byte* out) {
  BitWriter w(out);
  for (int k = 0; k < 3; ++k) w.put(c.mean[k], kMeanBits[k]);
  w.put(c.frame[0], 8);
  w.put(c.frame[1], 10);
  w.put(c.frame[2], 6);
  w.put(c.sigmaClass, kPositionClassBits);
  w.put(c.normalClass, kNormalClassBits);
  w.put(c.normalFrame[0], 8);
  w.put(c.normalFrame[1], 10);
  w.put(c.normalFrame[2], 6);
  w.put(c.color565, 16);
  w.put(c.colorFrame[0], 4);
  w.put(c.colorFrame[1], 3);
  w.put(c.colorFrame[2], 3);
  w.put(c.colorClass, kColorClassBits);
  w.put(c.flags, 8);
}

StatisticalNodeCode unpackStatisticalNode(const std::byte* in) {
  BitReader r(in);
  StatisticalNodeCode c;
  for (int k = 0; k < 3; ++k) c.mean[k] = r.get(kMeanBits[k]);
  c.frame[0] = r.get(8);
  c.frame[1] = r.get(10);
  c.frame[2] = r.get(6);
  c.sigmaClass = r.get(kPositionClassBits);
  c.normalClass = r.get(kNormalClassBits);
  c.normalFrame[0] = r.get(8);
  c.normalFrame[1] = r.get(10);
  c.normalFrame[2] = r.get(6);
  c.color565 = r.get(16);
  c.colorFrame[0] = r.get(4);
  c.colorFrame[1] = r.get(3);
  c.colorFrame[2] = r.get(3);
  c.colorClass = static_cast<std::uint8_t>(r.get(kColorClassBits));
  c.flags = static_cast<std::uint8_t>(r.get(8));
  return c;
}

std::array<std::array<float, 3>, 3> decodeFrame(FrameKind kind, const std::uint16_t code[3]) {
  const FrameBits b = frameBits(kind);
  const Axes a = frameFromAngles(codeAngle(code[0], b.theta, b.thetaMax, true),
                                 codeAngle(code[1], b.phi, 2 * kPi, false),
                                 codeAngle(code[2], b.psi, kPi, false));
  std::array<std::array<float, 3>, 3> out{};
  for (std::size_t i = 0; i < 3; ++i)
    for (std::size_t j = 0; j < 3; ++j) out[i][j] = static_cast<float>(a[i][j]);
  return out;
}

void encodeFrame(FrameKind kind, const std::array<std::array<double, 3>, 3>& axes,
                 std::uint16_t code[3]) {
  const FrameBits b = frameBits(kind);
  std::array<double, 3> f1 = axes[0], f3 = axes[2];
  if (b.hemisphere && f3[2] < 0) {
    // -f3 with -f1 keeps the frame right-handed and the same Gaussian.
    for (std::size_t k = 0; k < 3; ++k) {
      f3[k] = -f3[k];
      f1[k] = -f1[k];
    }
  }
  const double theta = std::acos(std::clamp(f3[2], -1.0, 1.0));
  const double phi = std::atan2(f3[1], f3[0]);
  code[0] = angleCode(theta, b.theta, b.thetaMax, true);
  code[1] = angleCode(phi, b.phi, 2 * kPi, false);
  std::array<double, 3> q3, x, y;
  baseFrame(codeAngle(code[0], b.theta, b.thetaMax, true),
            codeAngle(code[1], b.phi, 2 * kPi, false), q3, x, y);
  // f1 and -f1 are the same axis: psi in [0, pi).
  code[2] = angleCode(std::atan2(dot3(f1, y), dot3(f1, x)), b.psi, kPi, false);
}

float positionClassReference(const StatisticalNode* parent, const StatisticalPacketHeader& h) {
  if (parent != nullptr) return parent->sigma[0];
  const float e = std::max({h.extent[0], h.extent[1], h.extent[2]});
  return e > 0.0f ? e : 1.0f;
}

void encodeNodeMean(const double mean[3], const StatisticalNode* parent,
                    const StatisticalPacketHeader& h, std::uint16_t code[3]) {
  for (int k = 0; k < 3; ++k) {
    const double levels = double((1u << kMeanBits[k]) - 1);
    double unit = 0.0;  // in [0, 1]
    if (parent == nullptr) {
      unit = h.extent[k] > 0.0f ? (mean[k] - double(h.origin[k])) / double(h.extent[k]) : 0.0;
    } else {
      const double s = double(std::max(parent->sigma[k], kMeanRangeFloor * parent->sigma[0]));
      double d = 0.0;
      for (int j = 0; j < 3; ++j)
        d += (mean[j] - double(parent->mean[j])) * double(parent->axes[k][j]);
      unit = s > 0.0 ? (d / (double(kChildMeanRange) * s) + 1.0) / 2.0 : 0.5;
    }
    code[k] = static_cast<std::uint16_t>(std::round(std::clamp(unit, 0.0, 1.0) * levels));
  }
}

std::uint16_t encodeColor565(const double rgb[3]) {
  const auto q = [](double v, unsigned levels) {
    return static_cast<std::uint32_t>(std::round(std::clamp(v, 0.0, 255.0) / 255.0 * levels));
  };
  return static_cast<std::uint16_t>((q(rgb[0], 31) << 11) | (q(rgb[1], 63) << 5) | q(rgb[2], 31));
}

StatisticalNode decodeStatisticalNode(const StatisticalNodeCode& c, const StatisticalNode* parent,
                                      const StatisticalPacketHeader& h, const ClassTables& tables) {
  StatisticalNode n{};
  for (int k = 0; k < 3; ++k) {
    const double unit = c.mean[k] / double((1u << kMeanBits[k]) - 1);
    if (parent == nullptr)
      n.mean[k] = static_cast<float>(double(h.origin[k]) + unit * double(h.extent[k]));
  }
  if (parent != nullptr) {
    double offset[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      const double unit = c.mean[k] / double((1u << kMeanBits[k]) - 1);
      const double s = double(std::max(parent->sigma[k], kMeanRangeFloor * parent->sigma[0]));
      const double along = (2.0 * unit - 1.0) * double(kChildMeanRange) * s;
      for (int j = 0; j < 3; ++j) offset[j] += along * double(parent->axes[k][j]);
    }
    for (int j = 0; j < 3; ++j) n.mean[j] = static_cast<float>(double(parent->mean[j]) + offset[j]);
  }
  const auto frame = decodeFrame(FrameKind::Position, c.frame);
  const auto normalFrame = decodeFrame(FrameKind::Normal, c.normalFrame);
  const auto colorFrame = decodeFrame(FrameKind::Color, c.colorFrame);
  const float reference = positionClassReference(parent, h);
  const auto& sigma = tables.position.at(c.sigmaClass);
  const auto& sigmaNormal = tables.normal.at(c.normalClass);
  const auto& sigmaColor = tables.color.at(c.colorClass);
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = 0; j < 3; ++j) {
      n.axes[i][j] = frame[i][j];
      n.normalFrame[i][j] = normalFrame[i][j];
      n.colorAxes[i][j] = colorFrame[i][j];
    }
    n.sigma[i] = sigma[i] * reference;
    n.sigmaColor[i] = sigmaColor[i];
  }
  n.sigmaNormal[0] = sigmaNormal[0];
  n.sigmaNormal[1] = sigmaNormal[1];
  n.color[0] = float((c.color565 >> 11) & 31u) * 255.0f / 31.0f;
  n.color[1] = float((c.color565 >> 5) & 63u) * 255.0f / 63.0f;
  n.color[2] = float(c.color565 & 31u) * 255.0f / 31.0f;
  return n;
}

std::vector<std::byte> encodeClassTables(const ClassTables& t) {
  if (t.position.size() > (1u << kPositionClassBits) ||
      t.normal.size() > (1u << kNormalClassBits) || t.color.size() > (1u << kColorClassBits))
    throw Error("internal error: more statistical classes than their bits hold");
  ClassesHeader h{kClassesMagic,
                  kClassesVersion,
                  static_cast<std::uint16_t>(t.position.size()),
                  static_cast<std::uint16_t>(t.normal.size()),
                  static_cast<std::uint16_t>(t.color.size()),
                  0};
  std::vector<std::byte> out(sizeof h +
                             (t.position.size() * 3 + t.normal.size() * 2 + t.color.size() * 3) *
                                 sizeof(float));
  std::byte* p = out.data();
  std::memcpy(p, &h, sizeof h);
  p += sizeof h;
  const auto put = [&p](const auto& table) {
    const std::size_t bytes = table.size() * sizeof(table[0]);
    if (bytes > 0) std::memcpy(p, table.data(), bytes);
    p += bytes;
  };
  put(t.position);
  put(t.normal);
  put(t.color);
  return out;
}

ClassTables decodeClassTables(std::span<const std::byte> bytes, const std::string& where) {
  const std::string at = where + ": statistical classes: ";
  ClassesHeader h{};
  if (bytes.size() < sizeof h)
    throw InputError(at + "only " + std::to_string(bytes.size()) + " bytes, less than a header");
  std::memcpy(&h, bytes.data(), sizeof h);
  if (h.magic != kClassesMagic) throw InputError(at + "bad magic number");
  if (h.version != kClassesVersion)
    throw InputError(at + "version " + std::to_string(h.version) + ", this build reads " +
                     std::to_string(kClassesVersion));
  if (h.position == 0 || h.normal == 0 || h.color == 0 || h.position > (1u << kPositionClassBits) ||
      h.normal > (1u << kNormalClassBits) || h.color > (1u << kColorClassBits))
    throw InputError(at + "class counts " + std::to_string(h.position) + ", " +
                     std::to_string(h.normal) + ", " + std::to_string(h.color) +
                     " are outside 1..4096, 1..4096, 1..64");
  const std::size_t expected = sizeof h + (std::size_t{h.position} * 3 + std::size_t{h.normal} * 2 +
                                           std::size_t{h.color} * 3) *
                                              sizeof(float);
  if (bytes.size() != expected)
    throw InputError(at + std::to_string(bytes.size()) + " bytes, the counts need " +
                     std::to_string(expected));
  ClassTables t;
  t.position.resize(h.position);
  t.normal.resize(h.normal);
  t.color.resize(h.color);
  const std::byte* p = bytes.data() + sizeof h;
  const auto get = [&p](auto& table) {
    const std::size_t n = table.size() * sizeof(table[0]);
    std::memcpy(table.data(), p, n);
    p += n;
  };
  get(t.position);
  get(t.normal);
  get(t.color);
  checkTable(t.position, at, "position");
  checkTable(t.normal, at, "normal");
  checkTable(t.color, at, "colour");
  return t;
}

void extendStatisticalPacket(StatisticalPacketView& view, std::span<const std::byte> bytes,
                             const ClassTables& tables, const std::string& where) {
  const std::string at = where + ": statistical packet: ";
  StatisticalPacketHeader header{};
  if (bytes.size() < sizeof(StatisticalPacketHeader))
    throw InputError(at + "only " + std::to_string(bytes.size()) + " bytes, less than a header");
  std::memcpy(&header, bytes.data(), sizeof header);
  if (!view.nodes.empty() && std::memcmp(&header, &view.header, sizeof header) != 0)
    throw InputError(at + "the header changed between two prefixes of the packet");
  view.header = header;
  const StatisticalPacketHeader& h = view.header;
  if (h.magic != kStatisticalMagic) throw InputError(at + "bad magic number");
  if (h.version != kStatisticalVersion)
    throw InputError(at + "version " + std::to_string(h.version) + ", this build reads " +
                     std::to_string(kStatisticalVersion));
  for (std::size_t k = 0; k < 3; ++k)
    if (!std::isfinite(h.origin[k]) || !std::isfinite(h.extent[k]) || h.extent[k] < 0.0f)
      throw InputError(at + "the root's box is not finite");
  if (h.nodeCount == 0 || h.nodeCount % 2 == 0)
    throw InputError(at + std::to_string(h.nodeCount) +
                     " nodes: a binary hierarchy has an odd number");
  const std::uint64_t available = (bytes.size() - sizeof h) / kStatisticalNodeBytes;
  const auto count = static_cast<std::uint32_t>(std::min<std::uint64_t>(available, h.nodeCount));
  auto& withChildren = view.withChildren;  // breadth-first: the j-th has children 2j+1, 2j+2
  const auto from = static_cast<std::uint32_t>(view.nodes.size());
  if (count <= from) return;
  view.nodes.resize(count);
  for (std::uint32_t i = from; i < count; ++i) {
    const StatisticalNodeCode code =
        unpackStatisticalNode(bytes.data() + sizeof h + std::size_t{i} * kStatisticalNodeBytes);
    if (code.sigmaClass >= tables.position.size() || code.normalClass >= tables.normal.size() ||
        code.colorClass >= tables.color.size()) {
      view.nodes.resize(i);
      throw InputError(at + "node " + std::to_string(i) + " names a class outside the tables");
    }
    const StatisticalNode* parent = nullptr;
    std::uint32_t parentIndex = 0;
    if (i > 0) {
      const std::uint32_t j = (i - 1) / 2;
      if (j >= withChildren.size()) {
        view.nodes.resize(i);
        throw InputError(at + "node " + std::to_string(i) + " has no parent");
      }
      parentIndex = withChildren[j];
      parent = &view.nodes[parentIndex];
    }
    view.nodes[i] = decodeStatisticalNode(code, parent, h, tables);
    view.nodes[i].parent = parentIndex;
    if ((code.flags & kNodeHasChildren) != 0) {
      const std::uint64_t first = 2 * std::uint64_t{withChildren.size()} + 1;
      if (first + 1 >= h.nodeCount) {
        view.nodes.resize(i);
        throw InputError(at + "node " + std::to_string(i) + "'s children lie beyond the " +
                         std::to_string(h.nodeCount) + " nodes");
      }
      view.nodes[i].firstChild = static_cast<std::uint32_t>(first);
      withChildren.push_back(i);
    }
  }
  if (count == h.nodeCount && 2 * withChildren.size() + 1 != h.nodeCount)
    throw InputError(at + std::to_string(withChildren.size()) + " nodes with children need " +
                     std::to_string(2 * withChildren.size() + 1) + " nodes, the packet has " +
                     std::to_string(h.nodeCount));
}

StatisticalPacketView decodeStatisticalPacket(std::span<const std::byte> bytes,
                                              const ClassTables& tables, const std::string& where) {
  StatisticalPacketView view;
  extendStatisticalPacket(view, bytes, tables, where);
  return view;
}

StatisticalPacketView decodeStatisticalPacket(std::span<const Splat> records,
                                              const ClassTables& tables, const std::string& where) {
  return decodeStatisticalPacket(std::as_bytes(records), tables, where);
}

}  // namespace pointillist
