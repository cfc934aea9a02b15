#include "common/checksum.hpp"

#define XXH_INLINE_ALL
#include <xxhash.h>

namespace pointillist {

struct ChecksumStream::State {
  XXH3_state_t xxh;
};

std::uint64_t checksum64(const void* data, std::size_t size) {
  return XXH3_64bits(data, size);
}

ChecksumStream::ChecksumStream() : state_(std::make_unique<State>()) {
  XXH3_64bits_reset(&state_->xxh);
}
ChecksumStream::~ChecksumStream() = default;
ChecksumStream::ChecksumStream(ChecksumStream&&) noexcept = default;
ChecksumStream& ChecksumStream::operator=(ChecksumStream&&) noexcept = default;

void ChecksumStream::update(const void* data, std::size_t size) {
  XXH3_64bits_update(&state_->xxh, data, size);
}

std::uint64_t ChecksumStream::digest() const {
  return XXH3_64bits_digest(&state_->xxh);
}

}  // namespace pointillist
