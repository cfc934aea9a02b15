#include "preprocess/selection.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

namespace pointillist::preprocess {
namespace {

// The value std::nth_element puts at k, for every size up to 200 and every k,
// over distinct values, heavy duplicates (five values), and sorted and
// reversed input (median-of-three pivots meet their worst cases there).
TEST(Selection, KthSmallestIsTheValueNthElementFinds) {
  std::mt19937 rng(7);
  std::vector<float> values, spare, expected;
  for (int shape = 0; shape < 4; ++shape) {
    for (std::size_t n = 1; n <= 200; ++n) {
      for (std::size_t k = 0; k < n; k += 1 + n / 17) {
        values.resize(n);
        for (float& v : values) {
          v = shape == 1 ? static_cast<float>(rng() % 5)
                         : static_cast<float>(rng() % 100000) / 7.0f;
        }
        if (shape == 2) std::sort(values.begin(), values.end());
        if (shape == 3) std::sort(values.rbegin(), values.rend());
        expected = values;
        std::nth_element(expected.begin(), expected.begin() + static_cast<std::ptrdiff_t>(k),
                         expected.end());
        spare.assign(n, -1.0f);
        ASSERT_EQ(kthSmallest(values.data(), spare.data(), n, k), expected[k])
            << "shape " << shape << ", n " << n << ", k " << k;
      }
    }
  }
}

// The neighbour search selects 64-bit keys (distance bits above an index).
TEST(Selection, KthSmallestOfIntegerKeys) {
  std::mt19937_64 rng(3);
  std::vector<std::uint64_t> values, spare, expected;
  for (std::size_t n = 1; n <= 150; ++n) {
    for (std::size_t k = 0; k < n; k += 1 + n / 11) {
      values.resize(n);
      for (std::uint64_t& v : values) v = (rng() % 64) << 32 | (rng() % 1000);
      expected = values;
      std::nth_element(expected.begin(), expected.begin() + static_cast<std::ptrdiff_t>(k),
                       expected.end());
      spare.assign(n, 0);
      ASSERT_EQ(kthSmallest(values.data(), spare.data(), n, k), expected[k])
          << "n " << n << ", k " << k;
    }
  }
}

TEST(Selection, AllEqualValuesAndTheEnds) {
  std::vector<float> values(100, 2.5f), spare(100);
  EXPECT_EQ(kthSmallest(values.data(), spare.data(), 100, 0), 2.5f);
  values.assign(100, 2.5f);
  EXPECT_EQ(kthSmallest(values.data(), spare.data(), 100, 99), 2.5f);
  for (std::size_t i = 0; i < 100; ++i) values[i] = static_cast<float>((i * 37) % 100);
  EXPECT_EQ(kthSmallest(values.data(), spare.data(), 100, 0), 0.0f);
  for (std::size_t i = 0; i < 100; ++i) values[i] = static_cast<float>((i * 37) % 100);
  EXPECT_EQ(kthSmallest(values.data(), spare.data(), 100, 99), 99.0f);
}

}  // namespace
}  // namespace pointillist::preprocess
