#pragma once
// Selection of the k-th smallest of a few dozen values, as the radius
// estimation and the neighbour search do millions of times. The value is the one std::nth_element
// finds; the partitions write each value to both free ends of a buffer and
// advance one end, so they do not branch on the side a value falls on (a coin
// toss to the branch predictor, and the cost of std::nth_element on short
// arrays: about three times this on 50 random floats). T is a float or an
// unsigned integer.
#include <algorithm>
#include <cstddef>
#include <utility>

namespace pointillist::preprocess {

// The k-th smallest (0-based) of values[0, n), k < n, with no NaN among them.
// `values` and `spare` (n values each) are both overwritten.
template <class T>
T kthSmallest(T* values, T* spare, std::size_t n, std::size_t k) {
  while (n > 12) {
    const T a = values[0], b = values[n / 2], c = values[n - 1];
    const T pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));
    // Below the pivot to the front, the rest to the back.
    std::size_t low = 0, high = n;
    for (std::size_t i = 0; i < n; ++i) {
      const T v = values[i];
      spare[low] = v;
      spare[high - 1] = v;
      const bool below = v < pivot;
      low += below;
      high -= !below;
    }
    std::swap(values, spare);
    if (k < low) {
      n = low;
      continue;
    }
    // Of the rest, those equal to the pivot to the front: the pivot is among
    // them, so every round drops at least one value.
    T* const rest = values + low;
    const std::size_t restCount = n - low;
    std::size_t equal = 0;
    high = restCount;
    for (std::size_t i = 0; i < restCount; ++i) {
      const T v = rest[i];
      spare[equal] = v;
      spare[high - 1] = v;
      const bool same = !(pivot < v);
      equal += same;
      high -= !same;
    }
    k -= low;
    if (k < equal) return pivot;
    values = spare + equal;
    spare = rest;  // free now, and large enough
    n = restCount - equal;
    k -= equal;
  }
  std::sort(values, values + n);
  return values[k];
}

}  // namespace pointillist::preprocess
