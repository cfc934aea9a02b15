#include "common/shared_packets.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <sstream>
#include <utility>

#include "common/checksum.hpp"
#include "common/errors.hpp"

namespace pointillist {
namespace {

#ifdef MADV_POPULATE_READ
constexpr int kPopulateRead = MADV_POPULATE_READ;
#else
constexpr int kPopulateRead = 22;  // Linux 5.14's value; older kernels refuse it
#endif

std::string systemError(const std::string& what) {
  return what + ": " + std::strerror(errno);
}

}  // namespace

SharedSegment::SharedSegment(std::uint64_t byteSize, const std::string& name) {
  const int fd = memfd_create(name.c_str(), MFD_CLOEXEC);
  if (fd < 0) throw InputError(systemError("shared memory '" + name + "': memfd_create"));
  if (ftruncate(fd, static_cast<off_t>(byteSize)) != 0) {
    const std::string message =
        systemError("shared memory '" + name + "' of " + std::to_string(byteSize) + " bytes");
    close(fd);
    throw InputError(message);
  }
  struct stat status {};
  if (fstat(fd, &status) != 0) {
    const std::string message = systemError("shared memory '" + name + "': fstat");
    close(fd);
    throw InputError(message);
  }
  if (byteSize > 0) {
    void* mapped = mmap(nullptr, static_cast<std::size_t>(byteSize), PROT_READ | PROT_WRITE,
                        MAP_SHARED, fd, 0);
    if (mapped == MAP_FAILED) {
      const std::string message = systemError("shared memory '" + name + "': mmap");
      close(fd);
      throw InputError(message);
    }
    data_ = static_cast<std::byte*>(mapped);
  }
  id_ = {static_cast<std::uint32_t>(getpid()), fd, static_cast<std::uint64_t>(status.st_ino),
         byteSize};
}

SharedSegment::~SharedSegment() {
  if (data_ != nullptr) munmap(data_, static_cast<std::size_t>(id_.byteSize));
  close(id_.fd);
}

SharedSegmentView::SharedSegmentView(const SharedSegmentId& id, const std::string& owner)
    : id_(id), owner_(owner) {
  const std::string path = "/proc/" + std::to_string(id.pid) + "/fd/" + std::to_string(id.fd);
  const auto fail = [&](const std::string& what) {
    throw ProtocolError("cannot read " + owner + "'s shared packets (" + path + "): " + what +
                        "; run with --shared-packets off to copy them instead");
  };
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) fail(std::strerror(errno));
  struct stat status {};
  if (fstat(fd, &status) != 0) {
    const std::string error = std::strerror(errno);
    close(fd);
    fail(error);
  }
  if (static_cast<std::uint64_t>(status.st_ino) != id.inode ||
      static_cast<std::uint64_t>(status.st_size) != id.byteSize) {
    close(fd);
    fail("it is not the segment named (inode " + std::to_string(status.st_ino) + ", " +
         std::to_string(status.st_size) + " bytes; expected inode " + std::to_string(id.inode) +
         ", " + std::to_string(id.byteSize) + " bytes)");
  }
  if (id.byteSize > 0) {
    void* mapped =
        mmap(nullptr, static_cast<std::size_t>(id.byteSize), PROT_READ, MAP_SHARED, fd, 0);
    if (mapped == MAP_FAILED) {
      const std::string error = std::strerror(errno);
      close(fd);
      fail("mmap: " + error);
    }
    data_ = static_cast<const std::byte*>(mapped);
  }
  close(fd);  // the mapping keeps the file
  open_ = true;
}

SharedSegmentView::~SharedSegmentView() {
  release();
}

SharedSegmentView::SharedSegmentView(SharedSegmentView&& other) noexcept
    : id_(other.id_),
      owner_(std::move(other.owner_)),
      data_(std::exchange(other.data_, nullptr)),
      open_(std::exchange(other.open_, false)) {}

SharedSegmentView& SharedSegmentView::operator=(SharedSegmentView&& other) noexcept {
  if (this != &other) {
    release();
    id_ = other.id_;
    owner_ = std::move(other.owner_);
    data_ = std::exchange(other.data_, nullptr);
    open_ = std::exchange(other.open_, false);
  }
  return *this;
}

void SharedSegmentView::release() noexcept {
  if (data_ != nullptr)
    munmap(const_cast<std::byte*>(data_), static_cast<std::size_t>(id_.byteSize));
  data_ = nullptr;
  open_ = false;
}

std::span<const std::byte> SharedSegmentView::bytes(std::uint64_t offset,
                                                    std::uint64_t size) const {
  if (offset > id_.byteSize || size > id_.byteSize - offset) {
    throw ProtocolError(owner_ + "'s shared packets: bytes " + std::to_string(offset) + "+" +
                        std::to_string(size) + " are outside its " + std::to_string(id_.byteSize) +
                        "-byte segment");
  }
  if (size == 0) return {};
  return {data_ + offset, static_cast<std::size_t>(size)};
}

void SharedSegmentView::populate(std::span<const std::byte> bytes) {
  // Only what is about to be read: mapping the whole segment up front would
  // map pages no tile asks for.
  if (bytes.empty()) return;
  static const auto page = static_cast<std::uintptr_t>(sysconf(_SC_PAGESIZE));
  const auto first = reinterpret_cast<std::uintptr_t>(bytes.data()) / page * page;
  const auto end = reinterpret_cast<std::uintptr_t>(bytes.data() + bytes.size());
  madvise(reinterpret_cast<void*>(first), end - first, kPopulateRead);
}

bool processRuns(std::uint32_t pid) {
  // A killed process stays a zombie (state Z) until its parent reaps it, and
  // kill(pid, 0) still finds it; its descriptors are gone by then. Before
  // that, while it exits, its descriptors close with its state unchanged:
  // the kernel's PF_EXITING flag (stat's ninth field) says so (CI once saw
  // a render read a killed data-send's segment in that window and abort).
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  const std::string line((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
  const auto name = line.rfind(')');
  if (name == std::string::npos || name + 2 >= line.size()) return false;
  std::istringstream fields(line.substr(name + 2));
  std::string state;
  std::int64_t skipped = 0;  // ppid .. tpgid; tpgid is -1 without a terminal
  std::uint64_t flags = 0;
  fields >> state;
  for (int field = 4; field <= 8; ++field) fields >> skipped;
  fields >> flags;
  constexpr std::uint64_t kExiting = 0x4;  // PF_EXITING
  if (state.empty() || state == "Z" || state == "X" || state == "x") return false;
  return !fields.fail() ? (flags & kExiting) == 0 : true;
}

std::uint64_t thisMachineIdentity() {
  std::string identity;
  std::ifstream boot("/proc/sys/kernel/random/boot_id");
  std::getline(boot, identity);
  char host[256] = {};
  if (gethostname(host, sizeof host - 1) == 0) identity += std::string("/") + host;
  // The pid namespace too: a data-send's pid must name it for the reader.
  char space[64] = {};
  if (readlink("/proc/self/ns/pid", space, sizeof space - 1) > 0)
    identity += std::string("/") + space;
  return checksum64(identity.data(), identity.size());
}

}  // namespace pointillist
