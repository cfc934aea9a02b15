#pragma once
// What the format readers (PLY, XYZ/PTS, LAS, OFF) share: errors that name the
// file and the place, a buffered line/byte reader, strict number parsing,
// colour conversion and the point collector. Dispatching on the file type is
// readers.hpp's job; format readers include only this.
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <span>
#include <string_view>
#include <vector>

#include "common/splat.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {
namespace detail {

// Error helpers: "<file>: <where>: <message>".
[[noreturn]] void failFile(const std::filesystem::path& file, std::string_view message);
[[noreturn]] void failAtLine(const std::filesystem::path& file, std::uint64_t line,
                             std::string_view message);
[[noreturn]] void failAtByte(const std::filesystem::path& file, std::uint64_t byte,
                             std::string_view message);

// Buffered reader over one file that serves both text lines (with line numbers)
// and raw bytes (with byte offsets), so PLY can switch from header to body.
class FileReader {
 public:
  explicit FileReader(const std::filesystem::path& file);
  ~FileReader();
  FileReader(const FileReader&) = delete;
  FileReader& operator=(const FileReader&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::uint64_t size() const { return size_; }
  // Bytes consumed so far (the offset of the next unread byte).
  std::uint64_t offset() const { return fileOffset_ - (end_ - pos_); }
  // Number of the line last returned by readLine (1-based).
  std::uint64_t lineNumber() const { return line_; }

  // Next line without its "\n" / "\r\n"; false at end of file. The view stays
  // valid until the next call.
  bool readLine(std::string_view& line);
  // The next whole lines, at least `want` bytes of them where the file has
  // that many more, as one view that stays valid until the next call; empty
  // at end of file. Lines keep their "\n" (the file's last may have none).
  // For readers that cut lines on many threads: they count the lines there,
  // and pass the count to countLines for lineNumber().
  std::string_view readLineBlock(std::size_t want);
  void countLines(std::uint64_t lines) { line_ += lines; }
  // Copies up to n bytes; returns how many were available.
  std::size_t read(void* destination, std::size_t n);
  // Skips n bytes; returns how many were available.
  std::uint64_t skip(std::uint64_t n);

 private:
  bool refill();  // keeps [pos_, end_) and appends more; false when nothing was added

  std::filesystem::path path_;
  std::FILE* file_ = nullptr;
  std::uint64_t size_ = 0;
  std::uint64_t fileOffset_ = 0;  // bytes pulled from the file into buffer_
  std::vector<char> buffer_;
  std::size_t pos_ = 0;
  std::size_t end_ = 0;
  std::uint64_t line_ = 0;
};

// Whole lines of a file from a byte offset on, a block at a time, as views
// into a read-only mapping of a window of the file: the threads that parse a
// block read the page cache directly, where FileReader would first copy the
// block on one thread while the others wait. The window moves on with the
// blocks, so the mapped pages a process holds stay about one block (what
// --memory-mb counts). open() gives nothing where the file cannot be mapped
// (a pipe, a device); the caller then reads through FileReader.
class MappedLineBlocks {
 public:
  static std::unique_ptr<MappedLineBlocks> open(const std::filesystem::path& file,
                                                std::uint64_t offset);
  ~MappedLineBlocks();
  MappedLineBlocks(const MappedLineBlocks&) = delete;
  MappedLineBlocks& operator=(const MappedLineBlocks&) = delete;

  // As FileReader::readLineBlock: the next whole lines, at least `want` bytes
  // of them where the file has that many more (the file's last line may have
  // no "\n"); empty at the end. Valid until the next call. `line` (the
  // number of the line before the block) names a line too long to be text.
  std::string_view next(std::size_t want, std::uint64_t line);
  // The offset of the next byte not yet returned.
  std::uint64_t offset() const { return offset_; }
  std::uint64_t size() const { return size_; }

 private:
  MappedLineBlocks(std::filesystem::path path, int fd, std::uint64_t size, std::uint64_t offset);
  void unmap();

  std::filesystem::path path_;
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::uint64_t offset_ = 0;
  void* window_ = nullptr;
  std::size_t windowBytes_ = 0;
};

// Collects points, checks coordinates for NaN/Inf (refuses, or drops with a
// warning under ReadOptions::dropNonFinite), reports progress, refuses empty
// clouds.
class CloudBuilder {
 public:
  CloudBuilder(std::filesystem::path file, const ReadOptions& options);

  // Room for `expected` points in all (never more than `limit`, which the
  // file could hold), its pages mapped ahead; nothing when there is room.
  void reserve(std::uint64_t expected, std::uint64_t limit);
  // A better estimate, part way: when `expected` points would not fit, room
  // for 5 % more than that.
  void expect(std::uint64_t expected, std::uint64_t limit);
  // `line` or `byte` (one is 0) locates the point for messages.
  void add(const Splat& splat, std::uint64_t line, std::uint64_t byte) {
    Splat s = splat;
    prepare(s);
    addPrepared(s, line, byte);
  }
  // add in two halves, so readers can run the first on many threads: unit
  // normals and no negative radius (harmless on a non-finite splat), then the
  // finiteness check and the hand-over, in input order.
  static void prepare(Splat& splat) {
    const auto nx = static_cast<double>(splat.normal[0]), ny = static_cast<double>(splat.normal[1]),
               nz = static_cast<double>(splat.normal[2]);
    const double length = std::sqrt(nx * nx + ny * ny + nz * nz);
    if (length > 0.0) {
      splat.normal[0] = static_cast<float>(nx / length);
      splat.normal[1] = static_cast<float>(ny / length);
      splat.normal[2] = static_cast<float>(nz / length);
    }
    // Non-finite radii stay for addPrepared to refuse.
    if (std::isfinite(splat.radius) && !(splat.radius > 0.0f)) splat.radius = 0.0f;
  }
  void addPrepared(const Splat& splat, std::uint64_t line, std::uint64_t byte);
  // addPrepared for a run of prepared splats already known to be finite: one
  // copy, handed to the sink at the same points as one by one.
  // `allHaveNormals`: the reader checked that each has a normal, so finish
  // need not look again.
  void addPreparedFinite(std::span<const Splat> splats, bool allHaveNormals = false);
  // Room for n more points at the cloud's end, for a reader to decode into
  // on many threads instead of copying a decoded block over; empty when the
  // points go to a sink. Then keepRoom when all n are prepared and finite,
  // else giveBackRoom (and addPrepared one by one, for the messages).
  std::span<Splat> appendRoom(std::size_t n);
  void keepRoom(bool allHaveNormals);
  void giveBackRoom();
  // Throttled progress callback.
  void progress(std::uint64_t done, std::uint64_t total);
  // Points accepted so far (handed to a sink or held).
  std::uint64_t size() const { return flushed_ + cloud_.splats.size(); }
  PointCloud finish(bool hasNormals, bool hasColors, bool hasRadii);

 private:
  std::filesystem::path file_;
  const ReadOptions& options_;
  void flush();

  PointCloud cloud_;
  std::uint64_t flushed_ = 0;       // points handed to options_.sink
  std::size_t checkedNormals_ = 0;  // leading points of cloud_ known to have normals
  std::size_t roomBegin_ = 0;       // where appendRoom's room starts
  bool allNormals_ = true;          // over the flushed points
  bool allRadii_ = true;
  std::uint64_t dropped_ = 0;
  std::uint64_t firstDropLine_ = 0;
  std::uint64_t firstDropByte_ = 0;
  std::uint64_t lastProgress_ = 0;
};

// Inline, branch-free: the readers check every point.
inline bool isFinite(const Splat& splat) {
  const auto finite = [](float v) {
    return (std::bit_cast<std::uint32_t>(v) & 0x7f800000u) != 0x7f800000u;
  };
  return finite(splat.position[0]) & finite(splat.position[1]) & finite(splat.position[2]) &
         finite(splat.normal[0]) & finite(splat.normal[1]) & finite(splat.normal[2]) &
         finite(splat.radius);
}
// A coordinate a float can hold: finite and within float range.
bool fitsFloat(double value);
// A count or index read as a number: true when `value` is a whole number in
// [0, 2^64), stored in `count`; false for negative, fractional, NaN or huge ones
// (a plain cast of those is undefined behaviour).
bool wholeCount(double value, std::uint64_t& count);
Splat greySplat();  // zero normal, zero radius, grey colour
// Splits on blanks (and commas, used by some XYZ exporters).
void splitFields(std::string_view line, std::vector<std::string_view>& fields);
// Strict number parsing of a whole field (accepts nan/inf so they can be refused).
bool parseDouble(std::string_view field, double& value);
// Exactly `count` numbers (as parseDouble reads them) separated by blanks,
// and nothing else: the values splitFields and parseDouble would give, in
// one pass over the line. False for anything else (the caller then splits).
bool parseNumbers(std::string_view line, double* values, std::size_t count);
// A plain decimal at `at` ("-12.5", "3e-4": digits before any point and after
// it) with at most 19 digits and an exact fast conversion: its value, the
// bits std::from_chars gives, and the end of the number. nullptr for
// anything else, which std::from_chars then reads.
// Where 64 bytes from `at` can be read, runs of 8 digits are read at once.
const char* parseShortDecimal(const char* at, const char* end, double& value);
// The same a byte at a time (what parseShortDecimal does near `end`).
const char* parseShortDecimalBytes(const char* at, const char* end, double& value);
// A plain line at `at`: exactly `count` short decimals (parseShortDecimal's,
// without a '+'), blanks between and around them, then "\n" or `end`, with
// 64 bytes readable from each number: the position after the line, the
// values parseNumbers gives. nullptr for any other line (a comment, a blank
// line, another count, an exponent past the fast path, the file's last
// bytes), which the caller then reads as before.
const char* parsePlainLine(const char* at, const char* end, double* values, std::size_t count);
bool parseUnsigned(std::string_view field, std::uint64_t& value);
// Inline: three a point in the readers' loops.
inline std::uint8_t colorFromUnit(double value) {  // 0..1 -> 0..255, clamped
  if (!(value > 0.0)) return 0;
  if (value >= 1.0) return 255;
  return static_cast<std::uint8_t>(value * 255.0 + 0.5);
}
inline std::uint8_t colorFromByte(double value) {  // 0..255, rounded and clamped (NaN -> 0)
  if (!(value > 0.0)) return 0;
  if (value >= 255.0) return 255;
  return static_cast<std::uint8_t>(value + 0.5);
}

}  // namespace detail
}  // namespace pointillist::preprocess
