#pragma once
// Containers whose resize leaves new elements of trivial types unwritten:
// buffers that are written in full at once anyway (a received MPI payload, a
// reprojected image) are not zeroed first, which costs as much as a cheap
// pass over them.
#include <memory>
#include <utility>

namespace pointillist {

template <class T>
struct UninitializedAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <class U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

}  // namespace pointillist
