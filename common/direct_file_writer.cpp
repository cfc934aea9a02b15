#include "common/direct_file_writer.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <new>
#include <string>

#include "common/errors.hpp"

namespace pointillist {

void DirectFileWriter::AlignedDelete::operator()(std::byte* p) const {
  ::operator delete (p, std::align_val_t{kBlock});
}

DirectFileWriter::DirectFileWriter(const std::filesystem::path& file, bool tryDirect)
    : path_(file) {
  constexpr int kFlags = O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC;
  if (tryDirect) fd_ = ::open(file.c_str(), kFlags | O_DIRECT, 0666);
  direct_ = fd_ >= 0;
  if (fd_ < 0) fd_ = ::open(file.c_str(), kFlags, 0666);
  if (fd_ < 0) throw Error("cannot create " + file.string() + ": " + std::strerror(errno));
  buffer_.reset(static_cast<std::byte*>(::operator new (kBuffer, std::align_val_t{kBlock})));
}

DirectFileWriter::~DirectFileWriter() {
  if (fd_ >= 0) ::close(fd_);
}

void DirectFileWriter::write(const void* data, std::size_t size) {
  const auto* from = static_cast<const std::byte*>(data);
  size_ += size;
  while (size > 0) {
    const std::size_t n = std::min(size, kBuffer - fill_);
    std::memcpy(buffer_.get() + fill_, from, n);
    fill_ += n;
    from += n;
    size -= n;
    if (fill_ == kBuffer) {
      writeOut(fill_);
      fill_ = 0;
    }
  }
}

std::uint64_t DirectFileWriter::finish() {
  if (fill_ > 0) {
    const std::size_t padded = direct_ ? (fill_ + kBlock - 1) / kBlock * kBlock : fill_;
    std::memset(buffer_.get() + fill_, 0, padded - fill_);
    writeOut(padded);
    fill_ = 0;
  }
  const bool cut = ::ftruncate(fd_, static_cast<off_t>(size_)) == 0;
  const int error = errno;
  const bool closed = ::close(fd_) == 0;
  fd_ = -1;
  if (!cut || !closed) {
    throw Error("cannot write " + path_.string() + ": " + std::strerror(cut ? errno : error));
  }
  return size_;
}

void DirectFileWriter::stopDirect() {
  direct_ = false;
  const int flags = ::fcntl(fd_, F_GETFL);
  if (flags < 0 || ::fcntl(fd_, F_SETFL, flags & ~O_DIRECT) != 0) {
    throw Error("cannot write " + path_.string() + ": " + std::strerror(errno));
  }
}

void DirectFileWriter::writeOut(std::size_t bytes) {
  const std::byte* from = buffer_.get();
  while (bytes > 0) {
    const ssize_t n = ::write(fd_, from, bytes);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno == EINVAL && direct_) {
      stopDirect();  // opened, but not taken direct after all
      continue;
    }
    if (n <= 0) {
      throw Error("cannot write " + path_.string() + ": " +
                  (n < 0 ? std::strerror(errno) : "no room"));
    }
    from += n;
    bytes -= static_cast<std::size_t>(n);
    // A short direct write leaves the rest unaligned: finish it buffered.
    if (bytes > 0 && direct_) stopDirect();
  }
}

}  // namespace pointillist
