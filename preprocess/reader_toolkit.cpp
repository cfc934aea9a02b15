#include "preprocess/reader_toolkit.hpp"

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <iostream>
#include <limits>
#include <string>
#include <system_error>
#include <utility>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/errors.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {
namespace detail {

namespace {
constexpr std::size_t kInitialBuffer = std::size_t{1} << 20;
// A "line" longer than this is not text: refuse rather than grow without bound.
constexpr std::size_t kMaxLine = std::size_t{64} << 20;
}  // namespace

void failFile(const std::filesystem::path& file, std::string_view message) {
  throw InputError(file.string() + ": " + std::string(message));
}

void failAtLine(const std::filesystem::path& file, std::uint64_t line, std::string_view message) {
  throw InputError(file.string() + ": line " + std::to_string(line) + ": " + std::string(message));
}

void failAtByte(const std::filesystem::path& file, std::uint64_t byte, std::string_view message) {
  throw InputError(file.string() + ": byte " + std::to_string(byte) + ": " + std::string(message));
}

FileReader::FileReader(const std::filesystem::path& file) : path_(file) {
  std::error_code ec;
  const auto status = std::filesystem::status(file, ec);
  if (ec || !std::filesystem::exists(status)) failFile(file, "no such file");
  if (std::filesystem::is_directory(status)) failFile(file, "is a directory, not a file");
  file_ = std::fopen(file.c_str(), "rb");
  if (file_ == nullptr) failFile(file, std::string("cannot open: ") + std::strerror(errno));
  size_ = std::filesystem::file_size(file, ec);
  if (ec) size_ = 0;
  // Small files get a small buffer (it grows when a line or record needs it).
  buffer_.resize(std::clamp<std::size_t>(size_ + 1, 4096, kInitialBuffer));
}

FileReader::~FileReader() {
  if (file_ != nullptr) std::fclose(file_);
}

bool FileReader::refill() {
  if (pos_ > 0) {
    std::memmove(buffer_.data(), buffer_.data() + pos_, end_ - pos_);
    end_ -= pos_;
    pos_ = 0;
  }
  if (end_ == buffer_.size()) {
    if (buffer_.size() >= kMaxLine) failAtLine(path_, line_ + 1, "line too long (binary data?)");
    buffer_.resize(buffer_.size() * 2);
  }
  const std::size_t got = std::fread(buffer_.data() + end_, 1, buffer_.size() - end_, file_);
  if (got == 0 && std::ferror(file_) != 0) {
    failAtByte(path_, fileOffset_, std::string("read error: ") + std::strerror(errno));
  }
  end_ += got;
  fileOffset_ += got;
  return got > 0;
}

bool FileReader::readLine(std::string_view& line) {
  std::size_t scanFrom = pos_;
  for (;;) {
    const char* begin = buffer_.data() + scanFrom;
    const void* nl = std::memchr(begin, '\n', end_ - scanFrom);
    if (nl != nullptr) {
      const std::size_t at =
          static_cast<std::size_t>(static_cast<const char*>(nl) - buffer_.data());
      std::size_t stop = at;
      if (stop > pos_ && buffer_[stop - 1] == '\r') --stop;
      line = std::string_view(buffer_.data() + pos_, stop - pos_);
      pos_ = at + 1;
      ++line_;
      return true;
    }
    const std::size_t scanned = end_ - pos_;
    if (!refill()) {
      if (pos_ == end_) return false;
      std::size_t stop = end_;
      if (buffer_[stop - 1] == '\r') --stop;
      line = std::string_view(buffer_.data() + pos_, stop - pos_);
      pos_ = end_;
      ++line_;
      return true;
    }
    scanFrom = pos_ + scanned;
  }
}

std::string_view FileReader::readLineBlock(std::size_t want) {
  want = std::max<std::size_t>(want, 1);
  // Room for `want` bytes after the unread ones, so refill never grows the
  // buffer (it would take a long block for a long line).
  if (buffer_.size() < want + kInitialBuffer) {
    if (pos_ > 0) {
      std::memmove(buffer_.data(), buffer_.data() + pos_, end_ - pos_);
      end_ -= pos_;
      pos_ = 0;
    }
    buffer_.resize(want + kInitialBuffer);
  }
  bool more = true;
  while (end_ - pos_ < want && more) more = refill();
  for (;;) {
    const std::size_t scanned = end_ - pos_;
    if (scanned == 0) return {};
    const char* first = buffer_.data() + pos_;
    const void* last = ::memrchr(first, '\n', scanned);
    std::size_t take = 0;
    if (last != nullptr) {
      take = static_cast<std::size_t>(static_cast<const char*>(last) - first) + 1;
    } else if (!more) {
      take = scanned;  // the file's last line, without "\n"
    } else {
      // Not one whole line in the buffer: read on, as readLine would, up to
      // its limit on a line's length.
      if (buffer_.size() >= kMaxLine) failAtLine(path_, line_ + 1, "line too long (binary data?)");
      buffer_.resize(buffer_.size() * 2);
      while (end_ < buffer_.size() && more) more = refill();
      continue;
    }
    pos_ += take;
    return {first, take};
  }
}

std::unique_ptr<MappedLineBlocks> MappedLineBlocks::open(const std::filesystem::path& file,
                                                         std::uint64_t offset) {
  // Only regular files; O_NONBLOCK so a pipe that slipped past the check
  // cannot block the open waiting for a writer.
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) return nullptr;
  const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return nullptr;
  struct stat status {};
  if (::fstat(fd, &status) != 0 || !S_ISREG(status.st_mode)) {
    ::close(fd);
    return nullptr;
  }
  const auto size = static_cast<std::uint64_t>(status.st_size);
  return std::unique_ptr<MappedLineBlocks>(
      new MappedLineBlocks(file, fd, size, std::min(offset, size)));
}

MappedLineBlocks::MappedLineBlocks(std::filesystem::path path, int fd, std::uint64_t size,
                                   std::uint64_t offset)
    : path_(std::move(path)), fd_(fd), size_(size), offset_(offset) {}

MappedLineBlocks::~MappedLineBlocks() {
  unmap();
  if (fd_ >= 0) ::close(fd_);
}

void MappedLineBlocks::unmap() {
  if (window_ != nullptr) ::munmap(window_, windowBytes_);
  window_ = nullptr;
  windowBytes_ = 0;
}

std::string_view MappedLineBlocks::next(std::size_t want, std::uint64_t line) {
  unmap();
  if (offset_ >= size_) return {};
  const auto page = static_cast<std::uint64_t>(::sysconf(_SC_PAGESIZE));
  const std::uint64_t from = offset_ / page * page;
  const auto skip = static_cast<std::size_t>(offset_ - from);
  want = std::max<std::size_t>(want, 1);
  // A mapped page past the file's end faults (SIGBUS): a file cut short
  // since it was opened is refused first.
  struct stat status {};
  if (::fstat(fd_, &status) != 0 || static_cast<std::uint64_t>(status.st_size) < size_)
    failAtByte(path_, offset_, "the file shrank while it was being read");
  // The block ends at the first line end from `want` bytes on: the window
  // reaches a little past, and further where that line is long.
  std::size_t span = want + kInitialBuffer;
  for (;;) {
    const std::uint64_t rest = size_ - offset_;
    const bool toEnd = span >= rest;
    windowBytes_ = skip + static_cast<std::size_t>(toEnd ? rest : span);
    window_ = ::mmap(nullptr, windowBytes_, PROT_READ, MAP_PRIVATE, fd_, static_cast<off_t>(from));
    if (window_ == MAP_FAILED) {
      window_ = nullptr;
      failAtByte(path_, offset_, std::string("cannot map the file: ") + std::strerror(errno));
    }
    ::madvise(window_, windowBytes_, MADV_SEQUENTIAL);
    const std::string_view text(static_cast<const char*>(window_) + skip, windowBytes_ - skip);
    const std::size_t end = text.find('\n', std::min(want, text.size()) - 1);
    if (end == std::string_view::npos && !toEnd) {
      unmap();
      if (span - want >= kMaxLine) failAtLine(path_, line + 1, "line too long (binary data?)");
      span = want + 2 * (span - want);
      continue;
    }
    const std::size_t take = end == std::string_view::npos ? text.size() : end + 1;
    offset_ += take;
    return text.substr(0, take);
  }
}

std::size_t FileReader::read(void* destination, std::size_t n) {
  auto* out = static_cast<char*>(destination);
  std::size_t done = 0;
  while (done < n) {
    if (pos_ == end_ && !refill()) break;
    const std::size_t take = std::min(n - done, end_ - pos_);
    std::memcpy(out + done, buffer_.data() + pos_, take);
    pos_ += take;
    done += take;
  }
  return done;
}

std::uint64_t FileReader::skip(std::uint64_t n) {
  const std::uint64_t inBuffer = std::min<std::uint64_t>(n, end_ - pos_);
  pos_ += static_cast<std::size_t>(inBuffer);
  std::uint64_t rest = n - inBuffer;
  if (rest == 0) return n;
  rest = std::min(rest, size_ > fileOffset_ ? size_ - fileOffset_ : 0);
  if (rest > 0 && fseeko(file_, static_cast<off_t>(rest), SEEK_CUR) != 0) {
    failAtByte(path_, fileOffset_, std::string("seek failed: ") + std::strerror(errno));
  }
  fileOffset_ += rest;
  return inBuffer + rest;
}

CloudBuilder::CloudBuilder(std::filesystem::path file, const ReadOptions& options)
    : file_(std::move(file)), options_(options) {
  cloud_.source = file_.string();
}

void CloudBuilder::reserve(std::uint64_t expected, std::uint64_t limit) {
  // Never trust a header count for allocation: cap it by what the file can hold.
  std::uint64_t n = std::min(expected, limit);
  if (options_.sink) n = std::min<std::uint64_t>(n, options_.sinkBlock);
  if (n <= cloud_.splats.capacity()) return;
  cloud_.splats.reserve(static_cast<std::size_t>(n));
  // Readers decode on all threads and hand blocks over in one serial copy.
  populatePages(cloud_.splats.data() + cloud_.splats.size(),
                (cloud_.splats.capacity() - cloud_.splats.size()) * sizeof(Splat), 0);
}

void CloudBuilder::expect(std::uint64_t expected, std::uint64_t limit) {
  if (std::min(expected, limit) <= cloud_.splats.capacity()) return;
  // A margin, so that a figure that creeps up does not move the array again.
  reserve(expected + expected / 20, limit);
}

void CloudBuilder::addPrepared(const Splat& s, std::uint64_t line, std::uint64_t byte) {
  // prepare keeps a non-finite splat non-finite (an infinite normal component
  // turns into NaN), so the verdict is the input's.
  if (!isFinite(s)) {
    if (!options_.dropNonFinite) {
      const std::string message = "non-finite value (NaN or Inf) in point " +
                                  std::to_string(size() + dropped_) +
                                  " (pass --drop-non-finite to drop such points)";
      if (line > 0) failAtLine(file_, line, message);
      failAtByte(file_, byte, message);
    }
    if (dropped_ == 0) {
      firstDropLine_ = line;
      firstDropByte_ = byte;
    }
    ++dropped_;
    return;
  }
  cloud_.splats.push_back(s);
  if (options_.sink && cloud_.splats.size() >= options_.sinkBlock) flush();
}

void CloudBuilder::addPreparedFinite(std::span<const Splat> splats, bool allHaveNormals) {
  while (!splats.empty()) {
    std::size_t take = splats.size();
    if (options_.sink)
      take =
          std::min(take, options_.sinkBlock - std::min(options_.sinkBlock, cloud_.splats.size()));
    take = std::max<std::size_t>(take, 1);
    if (allHaveNormals && checkedNormals_ == cloud_.splats.size()) checkedNormals_ += take;
    cloud_.splats.insert(cloud_.splats.end(), splats.begin(),
                         splats.begin() + static_cast<std::ptrdiff_t>(take));
    splats = splats.subspan(take);
    if (options_.sink && cloud_.splats.size() >= options_.sinkBlock) flush();
  }
}

std::span<Splat> CloudBuilder::appendRoom(std::size_t n) {
  if (options_.sink) return {};
  roomBegin_ = cloud_.splats.size();
  cloud_.splats.resize(roomBegin_ + n);
  return std::span<Splat>(cloud_.splats).subspan(roomBegin_);
}

void CloudBuilder::keepRoom(bool allHaveNormals) {
  if (allHaveNormals && checkedNormals_ == roomBegin_) checkedNormals_ = cloud_.splats.size();
}

void CloudBuilder::giveBackRoom() {
  cloud_.splats.resize(roomBegin_);
}

void CloudBuilder::flush() {
  const auto& v = cloud_.splats;
  allNormals_ = allNormals_ && std::all_of(v.begin() + static_cast<std::ptrdiff_t>(checkedNormals_),
                                           v.end(), hasNormal);
  checkedNormals_ = 0;
  allRadii_ =
      allRadii_ && std::all_of(v.begin(), v.end(), [](const Splat& x) { return x.radius > 0.0f; });
  if (!v.empty()) options_.sink(v);
  flushed_ += v.size();
  cloud_.splats.clear();
}

void CloudBuilder::progress(std::uint64_t done, std::uint64_t total) {
  if (!options_.progress) return;
  const std::uint64_t step = std::max<std::uint64_t>(total / 100, std::uint64_t{1} << 16);
  if (done == total || done >= lastProgress_ + step) {
    lastProgress_ = done;
    options_.progress(done, total);
  }
}

PointCloud CloudBuilder::finish(bool hasNormals, bool hasColors, bool hasRadii) {
  if (dropped_ > 0) {
    std::cerr << "warning: " << file_.string() << ": dropped " << dropped_
              << " point(s) with NaN/Inf values (first at "
              << (firstDropLine_ > 0 ? "line " + std::to_string(firstDropLine_)
                                     : "byte " + std::to_string(firstDropByte_))
              << ")\n";
  }
  if (size() == 0) {
    if (dropped_ > 0) failFile(file_, "every point has NaN/Inf values; nothing left");
    failFile(file_, "contains no points");
  }
  if (options_.sink) flush();
  const auto& v = cloud_.splats;
  cloud_.hasNormals =
      hasNormals && allNormals_ &&
      std::all_of(v.begin() + static_cast<std::ptrdiff_t>(checkedNormals_), v.end(), hasNormal);
  cloud_.hasColors = hasColors;
  cloud_.hasRadii = hasRadii && allRadii_ &&
                    std::all_of(v.begin(), v.end(), [](const Splat& x) { return x.radius > 0.0f; });
  return std::move(cloud_);
}

bool fitsFloat(double value) {
  return std::isfinite(value) &&
         std::abs(value) <= static_cast<double>(std::numeric_limits<float>::max());
}

bool wholeCount(double value, std::uint64_t& count) {
  // 2^64 is exact in a double; every double below it converts without overflow.
  if (!(value >= 0.0) || !(value < 18446744073709551616.0) || value != std::floor(value)) {
    return false;
  }
  count = static_cast<std::uint64_t>(value);
  return true;
}

Splat greySplat() {
  Splat s{};
  s.color[0] = s.color[1] = s.color[2] = kDefaultGrey;
  s.color[3] = 255;
  return s;
}

namespace {
bool isBlank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == ',' || c == '\v' || c == '\f';
}
}  // namespace

namespace {

// Clinger's fast path: a significand below 2^53 and a power of ten up to
// 10^22 are both exact doubles, so one multiplication or division rounds
// the exact value once, as a correctly rounded parse does.
constexpr double kPowersOfTen[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                   1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                   1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
constexpr std::uint64_t kExactBelow = std::uint64_t{1} << 53;
// Room a number of the SWAR path may read: a sign, two runs of at most 24
// digits (three loads each, the third past 19 digits) and a point, and the
// 8 bytes of the last load.
constexpr std::ptrdiff_t kSwarRoom = 64;

// The run of digits that starts at p, of at most 8 (8 bytes at p must be
// readable): its length, and its value in `run`. Eight bytes are tested and
// converted at once (the byte loop was a third of parsing an XYZ scan).
[[gnu::always_inline]] inline unsigned digitRun(const char* p, std::uint64_t& run) {
  std::uint64_t x;
  std::memcpy(&x, p, 8);
  // A byte is a digit where its high nibble is 3 and adding 6 keeps it 3.
  // A carry out of a byte above 0xF9 lands in the next byte only, after the
  // first byte that is not a digit, so the first such byte is found right.
  constexpr std::uint64_t kHigh = 0xF0F0F0F0F0F0F0F0ull, kThrees = 0x3030303030303030ull;
  const std::uint64_t notDigit =
      ((x & kHigh) ^ kThrees) | (((x + 0x0606060606060606ull) & kHigh) ^ kThrees);
  const unsigned n = notDigit == 0 ? 8u : static_cast<unsigned>(std::countr_zero(notDigit)) / 8;
  if (n == 0) {
    run = 0;
    return 0;
  }
  // Digit values, the run moved to the top bytes (leading zeros below it);
  // a borrow from the bytes after the run only reaches bytes shifted out.
  x = (x - kThrees) << (8 * (8 - n));
  x = x * 10 + (x >> 8);  // pairs
  x = (((x & 0x000000FF000000FFull) * 0x000F424000000064ull) +
       (((x >> 16) & 0x000000FF000000FFull) * 0x0000271000000001ull)) >>
      32;
  run = x & 0xFFFFFFFFu;
  return n;
}

// Digits at p, 8 at a time, onto `significand`; stops after the run or past
// 19 digits in all (refused then).
[[gnu::always_inline]] inline const char* appendDigits(const char* p, std::uint64_t& significand,
                                                       int& digits) {
  static constexpr std::uint64_t kScale[] = {1,      10,      100,      1000,     10000,
                                             100000, 1000000, 10000000, 100000000};
  for (;;) {
    std::uint64_t run = 0;
    const unsigned n = digitRun(p, run);
    significand = significand * kScale[n] + run;  // wraps only past 19 digits
    digits += static_cast<int>(n);
    p += n;
    if (n < 8 || digits > 19) return p;
  }
}

// parseShortDecimal where kSwarRoom bytes from `at` can be read.
[[gnu::always_inline]] inline const char* parseShortDecimalSwar(const char* at, const char* end,
                                                                double& value) {
  const char* p = at;
  const bool negative = *p == '-';
  p += negative ? 1 : 0;
  std::uint64_t significand = 0;
  int digits = 0;
  p = appendDigits(p, significand, digits);
  if (digits == 0 || digits > 19) return nullptr;
  int scale = 0;
  if (*p == '.') {
    const int whole = digits;
    p = appendDigits(p + 1, significand, digits);
    if (digits == whole) return nullptr;  // "5.": from_chars decides
    scale = whole - digits;
  }
  // An exponent the byte loop reads; past 19 digits or 10^22 from_chars does.
  if (*p == 'e' || *p == 'E') return parseShortDecimalBytes(at, end, value);
  if (digits > 19 || significand >= kExactBelow || scale < -22) return nullptr;
  const auto exact = static_cast<double>(significand);
  const double magnitude = scale < 0 ? exact / kPowersOfTen[-scale] : exact;
  value = negative ? -magnitude : magnitude;
  return p;
}

}  // namespace

const char* parseShortDecimal(const char* at, const char* end, double& value) {
  return end - at >= kSwarRoom ? parseShortDecimalSwar(at, end, value)
                               : parseShortDecimalBytes(at, end, value);
}

const char* parseShortDecimalBytes(const char* at, const char* end, double& value) {
  const char* p = at;
  const bool negative = p < end && *p == '-';
  p += negative ? 1 : 0;
  std::uint64_t significand = 0;
  int digits = 0, scale = 0;
  const auto digit = [&](const char* q) { return q < end && *q >= '0' && *q <= '9'; };
  if (!digit(p)) return nullptr;  // ".5", "inf", "nan", "0x10": from_chars decides
  for (; digit(p); ++p, ++digits) significand = significand * 10 + static_cast<unsigned>(*p - '0');
  if (p < end && *p == '.') {
    ++p;
    if (!digit(p)) return nullptr;  // "5.": from_chars decides
    for (; digit(p); ++p, ++digits, --scale)
      significand = significand * 10 + static_cast<unsigned>(*p - '0');
  }
  if (p < end && (*p == 'e' || *p == 'E')) {
    const char* q = p + 1;
    const bool down = q < end && *q == '-';
    q += (q < end && (*q == '-' || *q == '+')) ? 1 : 0;
    if (!digit(q)) return nullptr;
    int exponent = 0;
    for (; digit(q); ++q) {
      if (exponent > 1000) return nullptr;
      exponent = exponent * 10 + (*q - '0');
    }
    scale += down ? -exponent : exponent;
    p = q;
  }
  // 19 digits cannot wrap 64 bits.
  if (digits > 19 || significand >= kExactBelow || scale < -22 || scale > 22) return nullptr;
  const auto exact = static_cast<double>(significand);
  const double magnitude = scale < 0 ? exact / kPowersOfTen[-scale] : exact * kPowersOfTen[scale];
  value = negative ? -magnitude : magnitude;
  return p;
}

bool parseNumbers(std::string_view line, double* values, std::size_t count) {
  const char* at = line.data();
  const char* const end = at + line.size();
  for (std::size_t i = 0; i < count; ++i) {
    while (at < end && isBlank(*at)) ++at;
    if (at < end && *at == '+') ++at;  // parseDouble allows one
    if (const char* stop = parseShortDecimal(at, end, values[i]);
        stop != nullptr && (stop == end || isBlank(*stop))) {
      at = stop;
      continue;
    }
    const auto result = std::from_chars(at, end, values[i]);
    // The number must be the whole field: a blank or the end follows it.
    if (result.ec != std::errc() || (result.ptr < end && !isBlank(*result.ptr))) return false;
    at = result.ptr;
  }
  while (at < end && isBlank(*at)) ++at;
  return at == end;
}

const char* parsePlainLine(const char* at, const char* end, double* values, std::size_t count) {
  for (std::size_t i = 0; i < count; ++i) {
    while (at < end && isBlank(*at)) ++at;
    if (end - at < kSwarRoom) return nullptr;
    at = parseShortDecimalSwar(at, end, values[i]);
    // A number ends in a blank or the line's end (end - at is above 0 here).
    if (at == nullptr || !(isBlank(*at) || *at == '\n')) return nullptr;
  }
  while (at < end && isBlank(*at)) ++at;
  if (at == end) return end;
  return *at == '\n' ? at + 1 : nullptr;
}

void splitFields(std::string_view line, std::vector<std::string_view>& fields) {
  fields.clear();
  std::size_t i = 0;
  const std::size_t n = line.size();
  while (i < n) {
    while (i < n && isBlank(line[i])) ++i;
    if (i == n) break;
    const std::size_t start = i;
    while (i < n && !isBlank(line[i])) ++i;
    fields.push_back(line.substr(start, i - start));
  }
}

bool parseDouble(std::string_view field, double& value) {
  if (!field.empty() && field.front() == '+') field.remove_prefix(1);
  if (field.empty()) return false;
  const char* end = field.data() + field.size();
  if (parseShortDecimal(field.data(), end, value) == end) return true;
  const auto result = std::from_chars(field.data(), end, value);
  return result.ec == std::errc() && result.ptr == end;
}

bool parseUnsigned(std::string_view field, std::uint64_t& value) {
  if (!field.empty() && field.front() == '+') field.remove_prefix(1);
  if (field.empty()) return false;
  const char* end = field.data() + field.size();
  const auto result = std::from_chars(field.data(), end, value);
  return result.ec == std::errc() && result.ptr == end;
}

}  // namespace detail
}  // namespace pointillist::preprocess
