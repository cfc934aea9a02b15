// Shared packets: another process maps a data-send's segment and reads the
// bytes written there; a segment that is not the one named is refused.
#include "common/shared_packets.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <numeric>
#include <vector>

#include "common/errors.hpp"

namespace pointillist {
namespace {

std::vector<std::byte> pattern(std::size_t size) {
  std::vector<std::byte> bytes(size);
  for (std::size_t i = 0; i < size; ++i) bytes[i] = static_cast<std::byte>((i * 131 + 7) % 251);
  return bytes;
}

// In a child process (another address space, as a render process has):
// 0 when `check` holds.
template <class Check>
int inChildProcess(Check check) {
  const pid_t child = fork();
  if (child == 0) _exit(check() ? 0 : 1);
  int status = 0;
  waitpid(child, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : 2;
}

TEST(SharedPackets, AnotherProcessReadsTheBytesWrittenInPlace) {
  const std::size_t size = 3 * 4096 + 100;  // not whole pages
  SharedSegment segment(size, "pointillist-test");
  const auto bytes = pattern(size);
  std::memcpy(segment.data(), bytes.data(), size);
  const SharedSegmentId id = segment.id();
  EXPECT_EQ(id.byteSize, size);
  EXPECT_EQ(id.pid, static_cast<std::uint32_t>(getpid()));
  // Written after the fork too: a mapping, not a copy.
  EXPECT_EQ(inChildProcess([&] {
              const SharedSegmentView view(id, "data-send rank 2");
              const auto all = view.bytes(0, size);
              const auto middle = view.bytes(4000, 300);  // across a page boundary
              return all.size() == size && std::memcmp(all.data(), bytes.data(), size) == 0 &&
                     std::memcmp(middle.data(), bytes.data() + 4000, 300) == 0;
            }),
            0);
}

TEST(SharedPackets, RefusesBytesOutsideTheSegment) {
  SharedSegment segment(1000, "pointillist-test");
  const SharedSegmentView view(segment.id(), "data-send rank 2");
  EXPECT_EQ(view.bytes(0, 1000).size(), 1000u);
  EXPECT_EQ(view.bytes(1000, 0).size(), 0u);
  EXPECT_THROW(view.bytes(999, 2), ProtocolError);
  EXPECT_THROW(view.bytes(1001, 0), ProtocolError);
  EXPECT_THROW(view.bytes(8, ~std::uint64_t{0}), ProtocolError);  // no wrap-around
}

TEST(SharedPackets, RefusesASegmentThatIsNotTheOneNamed) {
  SharedSegment segment(4096, "pointillist-test");
  SharedSegmentId wrongInode = segment.id();
  wrongInode.inode += 1;
  try {
    SharedSegmentView view(wrongInode, "data-send rank 2");
    FAIL() << "a segment of another inode was mapped";
  } catch (const ProtocolError& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("data-send rank 2"), std::string::npos) << message;
    EXPECT_NE(message.find("--shared-packets off"), std::string::npos) << message;
  }
  SharedSegmentId wrongSize = segment.id();
  wrongSize.byteSize = 8192;
  EXPECT_THROW(SharedSegmentView(wrongSize, "data-send rank 2"), ProtocolError);
  SharedSegmentId closed = segment.id();
  closed.fd = 100000;  // no such descriptor
  EXPECT_THROW(SharedSegmentView(closed, "data-send rank 2"), ProtocolError);
}

TEST(SharedPackets, AnEmptySegmentMapsNothing) {
  SharedSegment segment(0, "pointillist-test");
  const SharedSegmentView view(segment.id(), "data-send rank 2");
  EXPECT_TRUE(view.mapped());
  EXPECT_EQ(view.bytes(0, 0).size(), 0u);
  EXPECT_THROW(view.bytes(0, 1), ProtocolError);
}

TEST(SharedPackets, AViewMovesWithItsMapping) {
  SharedSegment segment(64, "pointillist-test");
  std::memset(segment.data(), 0x5a, 64);
  SharedSegmentView first(segment.id(), "data-send rank 2");
  EXPECT_FALSE(SharedSegmentView().mapped());
  SharedSegmentView second = std::move(first);
  EXPECT_TRUE(second.mapped());
  EXPECT_FALSE(first.mapped());  // NOLINT(bugprone-use-after-move): moved-from is empty
  EXPECT_EQ(second.bytes(0, 64)[63], std::byte{0x5a});
  first = std::move(second);
  EXPECT_EQ(first.bytes(0, 1)[0], std::byte{0x5a});
}

TEST(SharedPackets, AProcessThatEndedNoLongerRuns) {
  EXPECT_TRUE(processRuns(static_cast<std::uint32_t>(getpid())));
  const pid_t child = fork();
  if (child == 0) _exit(0);
  // Not yet reaped: a zombie, which kill(pid, 0) would still find.
  for (int i = 0; i < 200 && processRuns(static_cast<std::uint32_t>(child)); ++i) usleep(10000);
  EXPECT_FALSE(processRuns(static_cast<std::uint32_t>(child)));
  waitpid(child, nullptr, 0);
  EXPECT_FALSE(processRuns(static_cast<std::uint32_t>(child)));
}

TEST(SharedPackets, TheMachineIdentityIsStable) {
  EXPECT_EQ(thisMachineIdentity(), thisMachineIdentity());
  EXPECT_NE(thisMachineIdentity(), 0u);
}

}  // namespace
}  // namespace pointillist
