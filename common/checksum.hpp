#pragma once
// The dataset's checksum: XXH3-64 (xxHash, seed 0). It runs at memory speed,
// so data-send and render processes verify every packet they read or receive
// without it showing in a frame's CPU time (FNV-1a, format 2, took a quarter of
// a render process's drawing time).
#include <cstddef>
#include <cstdint>
#include <memory>

namespace pointillist {

std::uint64_t checksum64(const void* data, std::size_t size);

// The same checksum over bytes given in pieces.
class ChecksumStream {
 public:
  ChecksumStream();
  ~ChecksumStream();
  ChecksumStream(ChecksumStream&&) noexcept;
  ChecksumStream& operator=(ChecksumStream&&) noexcept;
  void update(const void* data, std::size_t size);
  std::uint64_t digest() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace pointillist
