#include "preprocess/las_reader.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "preprocess/reader_toolkit.hpp"

namespace pointillist::preprocess {
namespace {

using detail::failAtByte;

// Offsets in the public header block (LAS 1.4 R15, table 3).
constexpr std::size_t kVersionMajor = 24;
constexpr std::size_t kHeaderSize = 94;
constexpr std::size_t kOffsetToPoints = 96;
constexpr std::size_t kPointFormat = 104;
constexpr std::size_t kRecordLength = 105;
constexpr std::size_t kLegacyCount = 107;
constexpr std::size_t kScale = 131;
constexpr std::size_t kOffset = 155;
constexpr std::size_t kCount64 = 247;
constexpr std::size_t kMinHeader = 227;  // LAS 1.0-1.2
constexpr std::size_t kHeader14 = 375;

// Little-endian decoding that does not depend on the host's byte order.
std::uint64_t le(const unsigned char* p, std::size_t n) {
  std::uint64_t v = 0;
  for (std::size_t i = n; i-- > 0;) v = (v << 8) | p[i];
  return v;
}
std::int32_t leI32(const unsigned char* p) {
  const auto u = static_cast<std::uint32_t>(le(p, 4));
  std::int32_t v;
  std::memcpy(&v, &u, 4);
  return v;
}
double leF64(const unsigned char* p) {
  const std::uint64_t u = le(p, 8);
  double v;
  std::memcpy(&v, &u, 8);
  return v;
}

struct FormatInfo {
  std::size_t minLength;
  int rgbAt;  // byte offset of R,G,B (uint16 each) in the record, or -1
};

// Point data record formats 0-10 (formats 4,5,9,10 add waveform packets).
bool formatInfo(unsigned id, FormatInfo& info) {
  static constexpr FormatInfo kFormats[] = {
      {20, -1}, {28, -1}, {26, 20}, {34, 28}, {57, -1}, {63, 28},
      {30, -1}, {36, 30}, {38, 30}, {59, -1}, {67, 30},
  };
  if (id >= std::size(kFormats)) return false;
  info = kFormats[id];
  return true;
}

}  // namespace

PointCloud readLas(const std::filesystem::path& file, const ReadOptions& options) {
  detail::FileReader reader(file);
  detail::CloudBuilder builder(file, options);

  std::array<unsigned char, kHeader14> h{};
  const std::size_t got = reader.read(h.data(), kMinHeader);
  if (got < 4 || std::memcmp(h.data(), "LASF", 4) != 0) {
    failAtByte(file, 0, "not a LAS file (no 'LASF' signature)");
  }
  if (got < kMinHeader) failAtByte(file, got, "truncated LAS header");
  const unsigned major = h[kVersionMajor];
  const unsigned minor = h[kVersionMajor + 1];
  if (major != 1 || minor > 4) {
    failAtByte(file, kVersionMajor,
               "unsupported LAS version " + std::to_string(major) + "." + std::to_string(minor) +
                   " (expected 1.0 to 1.4)");
  }
  const auto headerSize = static_cast<std::size_t>(le(&h[kHeaderSize], 2));
  if (headerSize < kMinHeader) {
    failAtByte(file, kHeaderSize, "header size " + std::to_string(headerSize) + " is too small");
  }
  const std::size_t wanted = std::min(headerSize, kHeader14) - kMinHeader;
  if (reader.read(h.data() + kMinHeader, wanted) != wanted) {
    failAtByte(file, reader.offset(), "truncated LAS header");
  }
  const std::uint64_t pointOffset = le(&h[kOffsetToPoints], 4);
  const unsigned formatByte = h[kPointFormat];
  // Bit 7 (and bit 6 in old LASzip files) flags compressed point data.
  if ((formatByte & 0xC0U) != 0) {
    failAtByte(file, kPointFormat,
               "compressed (LAZ) point data is not supported; decompress it first, e.g. "
               "`laszip -i in.laz -o out.las`");
  }
  FormatInfo format{};
  if (!formatInfo(formatByte, format)) {
    failAtByte(file, kPointFormat, "unknown point data format " + std::to_string(formatByte));
  }
  const auto recordLength = static_cast<std::size_t>(le(&h[kRecordLength], 2));
  if (recordLength < format.minLength) {
    failAtByte(file, kRecordLength,
               "point record length " + std::to_string(recordLength) + " is too short for format " +
                   std::to_string(formatByte) + " (needs " + std::to_string(format.minLength) +
                   ")");
  }
  std::uint64_t count = le(&h[kLegacyCount], 4);
  if (minor >= 4 && headerSize >= kHeader14) {
    const std::uint64_t count64 = le(&h[kCount64], 8);
    if (count64 != 0 || formatByte >= 6) count = count64;
  }
  double scale[3];
  double offset[3];
  for (std::size_t k = 0; k < 3; ++k) {
    scale[k] = leF64(&h[kScale + 8 * k]);
    offset[k] = leF64(&h[kOffset + 8 * k]);
    if (!std::isfinite(scale[k]) || scale[k] == 0.0 || !std::isfinite(offset[k])) {
      failAtByte(file, kScale + 8 * k, "invalid scale factor or offset");
    }
  }
  if (pointOffset < headerSize) {
    failAtByte(file, kOffsetToPoints,
               "offset to point data (" + std::to_string(pointOffset) + ") lies inside the header");
  }
  // Variable length records (and any header extension) are skipped.
  const std::uint64_t gap = pointOffset - reader.offset();
  if (reader.skip(gap) != gap) {
    failAtByte(file, reader.offset(),
               "file ends before the point data (offset " + std::to_string(pointOffset) + ")");
  }
  if (count == 0) detail::failFile(file, "contains no points (header point count is 0)");

  const std::uint64_t available =
      (reader.size() - std::min(reader.size(), pointOffset)) / recordLength;
  builder.reserve(count, available);
  const bool hasRgb = format.rgbAt >= 0;
  const auto channel = [&](const unsigned char* record, std::size_t k) {
    return static_cast<std::uint16_t>(
        le(record + static_cast<std::size_t>(format.rgbAt) + 2 * k, 2));
  };
  // The standard says 16-bit colour, but many writers store 0..255: colours
  // are scaled down only when some channel uses the high byte. In memory that
  // is decided at the end; streaming (a sink) points leave as they are read,
  // so a first pass over the records finds the largest channel.
  int shift = -1;  // unknown yet
  if (hasRgb && options.sink) {
    detail::FileReader scan(file);
    scan.skip(pointOffset);
    std::uint16_t largest = 0;
    std::vector<unsigned char> record(recordLength);
    for (std::uint64_t i = 0; i < count && scan.read(record.data(), recordLength) == recordLength;
         ++i)
      for (std::size_t k = 0; k < 3; ++k) largest = std::max(largest, channel(record.data(), k));
    shift = largest > 255 ? 8 : 0;
  }
  std::vector<std::array<std::uint16_t, 3>> rgb;
  std::uint16_t maxChannel = 0;
  if (hasRgb && shift < 0) rgb.reserve(static_cast<std::size_t>(std::min(count, available)));

  std::vector<unsigned char> record(recordLength);
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::uint64_t at = reader.offset();
    if (reader.read(record.data(), recordLength) != recordLength) {
      failAtByte(file, at,
                 "truncated point data (expected " + std::to_string(count) + " points, got " +
                     std::to_string(i) + ")");
    }
    Splat s = detail::greySplat();
    for (std::size_t k = 0; k < 3; ++k) {
      const double v = static_cast<double>(leI32(&record[4 * k])) * scale[k] + offset[k];
      s.position[k] = static_cast<float>(v);
    }
    if (hasRgb && shift >= 0) {
      for (std::size_t k = 0; k < 3; ++k)
        s.color[k] = static_cast<std::uint8_t>(channel(record.data(), k) >> shift);
    }
    const std::uint64_t before = builder.size();
    builder.add(s, 0, at);
    if (hasRgb && shift < 0 && builder.size() > before) {
      std::array<std::uint16_t, 3> c{};
      for (std::size_t k = 0; k < 3; ++k) {
        c[k] = channel(record.data(), k);
        maxChannel = std::max(maxChannel, c[k]);
      }
      rgb.push_back(c);
    }
    if ((i & 8191) == 0) builder.progress(reader.offset(), reader.size());
  }
  builder.progress(reader.size(), reader.size());
  PointCloud cloud = builder.finish(false, hasRgb, false);
  if (hasRgb && shift < 0) {
    const unsigned down = maxChannel > 255 ? 8U : 0U;
    for (std::size_t i = 0; i < cloud.splats.size(); ++i) {
      for (std::size_t k = 0; k < 3; ++k) {
        cloud.splats[i].color[k] = static_cast<std::uint8_t>(rgb[i][k] >> down);
      }
    }
  }
  return cloud;
}

}  // namespace pointillist::preprocess
