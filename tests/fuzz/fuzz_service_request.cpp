// libFuzzer target: the rendering service's request parser and checks, the
// first thing every message from a client meets (on either socket). A
// RequestError is the refusal a bad message should get; anything else is a
// finding.
#include <cstddef>
#include <cstdint>
#include <span>

#include "service/core/request_validation.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const pointillist::service::RequestLimits limits;
  const std::span<const std::byte> bytes(reinterpret_cast<const std::byte*>(data), size);
  for (const bool streamSocket : {false, true}) {
    try {
      const auto request = pointillist::service::parseRequest(bytes, limits, streamSocket);
      (void)request;
    } catch (const pointillist::service::RequestError&) {
    }
  }
  return 0;
}
