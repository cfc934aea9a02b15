// The dataset's points.bin writer: the same bytes direct or through the page
// cache, across whole buffers and a last block that is not whole.
#include "common/direct_file_writer.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "common/errors.hpp"

namespace pointillist {
namespace {

std::vector<std::byte> readAll(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::vector<char> chars{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  std::vector<std::byte> bytes(chars.size());
  for (std::size_t i = 0; i < chars.size(); ++i) bytes[i] = static_cast<std::byte>(chars[i]);
  return bytes;
}

TEST(DirectFileWriter, WritesTheSameBytesDirectOrBuffered) {
  const auto dir = std::filesystem::path(::testing::TempDir()) /
                   ("pointillist-direct-writer-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  // More than two buffers, in pieces that straddle their ends, and a tail
  // that is no whole block.
  std::vector<std::byte> expected(2 * DirectFileWriter::kBuffer + 3 * DirectFileWriter::kBlock +
                                  123);
  std::uint32_t state = 12345;
  for (std::byte& b : expected) {
    state = state * 1664525u + 1013904223u;
    b = static_cast<std::byte>(state >> 24);
  }
  const std::size_t pieces[] = {1, 4095, 123457, 9u << 20, 77};
  for (const bool tryDirect : {true, false}) {
    const auto file = dir / (tryDirect ? "direct.bin" : "buffered.bin");
    DirectFileWriter writer(file, tryDirect);
    if (!tryDirect) {
      EXPECT_FALSE(writer.direct());
    }
    std::size_t at = 0;
    for (std::size_t k = 0; at < expected.size(); ++k) {
      const std::size_t n = std::min(pieces[k % std::size(pieces)], expected.size() - at);
      writer.write(expected.data() + at, n);
      at += n;
    }
    writer.write(expected.data(), 0);
    EXPECT_EQ(writer.size(), expected.size());
    EXPECT_EQ(writer.finish(), expected.size());
    EXPECT_EQ(std::filesystem::file_size(file), expected.size()) << file;
    EXPECT_TRUE(readAll(file) == expected) << file;
  }
  // An empty file stays empty.
  DirectFileWriter empty(dir / "empty.bin");
  EXPECT_EQ(empty.finish(), 0u);
  EXPECT_EQ(std::filesystem::file_size(dir / "empty.bin"), 0u);
  std::filesystem::remove_all(dir);
}

TEST(DirectFileWriter, NamesTheFileItCannotCreate) {
  try {
    DirectFileWriter writer("/nonexistent-pointillist-dir/points.bin");
    FAIL() << "created a file in a directory that does not exist";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-pointillist-dir/points.bin"),
              std::string::npos);
  }
}

}  // namespace
}  // namespace pointillist
