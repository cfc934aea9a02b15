#pragma once
// The inner loops of the neighbour grid's search, in SIMD (Highway, one binary
// for every x86-64 with the widest vectors the machine has): squared
// distances from a query to a block of candidates, keeping those within a
// bound. The distances are the scalar code's floats, bit for bit: explicit
// multiplies and adds in its order, no fused multiply-add.
#include <cstddef>
#include <cstdint>

namespace pointillist::preprocess {

// For the n candidates (columns x, y, z and ids), the squared distances to p, (x - p0)^2 + (y -
// p1)^2 + (z - p2)^2 evaluated left to right, of those at most `bound`, and
// their ids, packed to the front of distance2 and idOut in candidate order.
// Both outputs need room for n values. Returns how many were kept.
std::size_t candidatesWithin(const float* x, const float* y, const float* z,
                             const std::uint32_t* id, std::size_t n, const float p[3], float bound,
                             float* distance2, std::uint32_t* idOut);

// Values past n that sortDistinctKeys may overwrite: a vector of the widest
// target, less one.
inline constexpr std::size_t kSortKeysPad = 7;

// The n keys, distinct, ascending into `sorted` (room for n): each goes to
// the place given by how many keys are below it. No branches, and n * n /
// lanes compares: for the few dozen candidates a query keeps, cheaper than a
// selection and a sort. `keys` needs room for n + kSortKeysPad values; those
// past n are overwritten.
void sortDistinctKeys(std::uint64_t* keys, std::size_t n, std::uint64_t* sorted);

}  // namespace pointillist::preprocess
