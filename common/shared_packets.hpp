#pragma once
// Packets that render processes on the data-send's machine read in place.
//
// A data-send process keeps the packets it owns in an anonymous memory file
// (memfd) and holds it open for its whole life. A process of the same machine
// maps that file read-only through /proc/<pid>/fd/<fd> (the access CMA
// transfers already need: same user, no ptrace restriction on reading), so a
// data packet between them names where its parts lie instead of carrying them:
// the MPI copy, the sender's gathering of parts and the checksum of bytes that
// never travelled all go. Across machines packets are copied as before.
//
// A mapping outlives the data-send process: a render keeps what it mapped if
// its data-send is lost.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace pointillist {

// What another process needs to map a segment. `inode` catches a descriptor
// number the owner has closed and reused.
struct SharedSegmentId {
  std::uint32_t pid = 0;
  std::int32_t fd = -1;
  std::uint64_t inode = 0;
  std::uint64_t byteSize = 0;
  bool operator==(const SharedSegmentId&) const = default;
};

// The owner's side: a writable memory file of a fixed size.
class SharedSegment {
 public:
  // `name` shows in /proc/<pid>/fd and in errors. Throws InputError when the
  // system refuses (no memfd, no memory).
  SharedSegment(std::uint64_t byteSize, const std::string& name);
  ~SharedSegment();
  SharedSegment(const SharedSegment&) = delete;
  SharedSegment& operator=(const SharedSegment&) = delete;

  std::byte* data() { return data_; }
  const std::byte* data() const { return data_; }
  std::uint64_t size() const { return id_.byteSize; }
  const SharedSegmentId& id() const { return id_; }

 private:
  SharedSegmentId id_;
  std::byte* data_ = nullptr;
};

// A reader's side: another process's segment, mapped read-only.
class SharedSegmentView {
 public:
  SharedSegmentView() = default;
  // Throws ProtocolError naming `owner` (e.g. "data-send rank 2") when the
  // segment cannot be opened or is not the one `id` names.
  SharedSegmentView(const SharedSegmentId& id, const std::string& owner);
  ~SharedSegmentView();
  SharedSegmentView(SharedSegmentView&& other) noexcept;
  SharedSegmentView& operator=(SharedSegmentView&& other) noexcept;

  const SharedSegmentId& id() const { return id_; }
  bool mapped() const { return open_; }
  // Bytes [offset, offset + size); throws ProtocolError when they are not all
  // inside the segment.
  std::span<const std::byte> bytes(std::uint64_t offset, std::uint64_t size) const;
  // Maps the pages of `bytes` in one call before they are read: a page fault
  // costs microseconds on a VM (where the kernel lacks MADV_POPULATE_READ,
  // before Linux 5.14, they fault as read).
  static void populate(std::span<const std::byte> bytes);

 private:
  void release() noexcept;
  SharedSegmentId id_;
  std::string owner_;
  const std::byte* data_ = nullptr;  // none for an empty segment
  bool open_ = false;
};

// Whether process `pid` still runs: a segment whose owner ended can no longer
// be opened (a mapping made before stays valid).
bool processRuns(std::uint32_t pid);

// Identifies this machine (its kernel's boot id, the host name and the pid
// namespace): two processes with the same identity can map each other's
// segments, and a pid one of them names is the same process for the other. A host name
// of its own (a network-namespace "host", deploy/netns-cluster.sh) counts as
// another machine, so packets cross its simulated links.
std::uint64_t thisMachineIdentity();

}  // namespace pointillist
