#pragma once
// Seed 000: a top-level cell's points factored into interacting vertex and
// transformation streams (common/instanced_section.hpp).
//
//  1. Quantize the cell's points to a grid whose step follows the cell's splat
//     radius (a splat hides an error well below its radius), at most 2^maxBits
//     voxels a side (the paper's 7-bit grid).
//  2. The palette: the most common translations between occupied voxels, the
//     peaks of their autocorrelation computed with FFTW on a zero-padded grid
//     (seed 000 §5), so no translation wraps around.
//  3. The vertex-transformation table (§4): bit i of vertex j's column is set
//     when voxel q_j + t_i holds a point that j may stand for. Attributes
//     survive by copying: a generated point takes its source vertex's colour,
//     normal and radius, so the table admits only pairs whose attributes agree
//     within the tolerances below.
//  4. Pools chosen greedily (§4.1): the vertex with most ones, its rows, then
//     every vertex by its ones in those rows, accepted when it newly covers
//     more than acceptShare of them; covered points leave the table (§4.2).
//     Tags hold a bit only for a translation that reaches a point no one
//     generates yet, so every quantized point is generated exactly once.
//  5. Points no pool covers (and second points in one voxel) stay plain splats.
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "common/dataset_writer.hpp"
#include "common/instanced_section.hpp"
#include "common/splat.hpp"

namespace pointillist::preprocess {

struct InstancingOptions {
  unsigned maxBits = 7;             // finest grid: 2^maxBits voxels along the cell's longest side
  double stepShare = 0.5;           // grid step as a share of the cell's median splat radius
  std::uint32_t paletteSize = 256;  // the paper keeps the 256 most common translations
  // Palette translations reach at most this many voxels along an axis: a
  // quarter of the 7-bit grid, and the FFT pads N + 32 instead of 2N - 1.
  std::int32_t paletteWindow = 32;
  // Small pools tile a surface better than the paper's 88 translations (on the
  // built-in city 8 translations cover 63 % of the points, 64 cover 30 %);
  // every pool is a draw call.
  std::uint32_t maxPools = 4;
  std::uint32_t poolTranslations = 8;  // null translation included, at most kPoolTranslations
  double acceptShare = 0.25;           // §4.1: new coverage above 25 % of the pool's translations
  std::uint32_t minPoolPoints = 32;    // a smaller pool is not worth a draw call
  std::uint32_t minCellPoints = 64;    // smaller cells stay plain
  int colorTolerance = 24;             // largest RGBA channel difference a copy may carry
  double normalToleranceDegrees = 25.0;
  double radiusTolerance = 0.25;  // relative
  double keepShare = 0.9;         // keep a section only below this share of the plain bytes
  // Sections cover subtrees of at most this many points (instancingUnits): a
  // level of detail draws a unit whole, so units much larger than a leaf
  // draw points the walk would have left coarse.
  std::uint32_t unitPoints = 1024;
};

struct QuantizedCell {
  std::array<float, 3> origin{};
  std::array<float, 3> high{};  // the points' largest coordinates
  float step = 1.0f;
  unsigned bits = 1;
  std::array<std::int32_t, 3> dims{1, 1, 1};  // voxels per axis, each at most 2^bits
  std::vector<Voxel> voxels;                  // one per input point
};
QuantizedCell quantizeCell(std::span<const Splat> points, const InstancingOptions& options);

struct TranslationCount {
  std::array<std::int32_t, 3> t{};
  std::uint32_t count = 0;  // ordered pairs of occupied voxels it maps
  bool operator==(const TranslationCount&) const = default;
};

// The `limit` most common non-null translations among distinct occupied
// voxels inside `dims`, no component beyond +-window, counted by FFT
// autocorrelation; only counts of at least 2; by count descending, then t
// ascending. Thread-safe.
std::vector<TranslationCount> translationPalette(std::span<const Voxel> occupied,
                                                 const std::array<std::int32_t, 3>& dims,
                                                 std::size_t limit, std::int32_t window = 32);
// Every non-null translation's count by comparing all pairs, sorted by t (tests).
std::vector<TranslationCount> bruteForceTranslationCounts(std::span<const Voxel> occupied);

// Wall time spent in FFTs by this thread, and FFT shapes planned (statistics).
double fftSecondsThisThread();
std::size_t fftPlansMade();
// FFTW wisdom lives in $XDG_CACHE_HOME/pointillist (or ~/.cache/pointillist).
// A shape it knows is planned measured; a new one is estimated at once, and
// this measures the new shapes within the budget and saves the wisdom for the
// next runs. Returns the shapes measured.
std::size_t saveFftWisdom(double budgetSeconds = 2.0);

struct InstancingStats {
  std::uint64_t points = 0;
  std::uint64_t covered = 0;  // generated by pools
  std::uint64_t pools = 0;
  std::uint64_t vertices = 0;
  std::uint64_t translations = 0;
  std::uint64_t vertexBytes = 0;  // the paper's accounting: vertex, transformation, tag
  std::uint64_t translationBytes = 0;
  std::uint64_t tagBytes = 0;
  std::uint64_t sectionBytes = 0;    // every section: headers, remainder, padding
  std::uint64_t plainBytes = 0;      // the same points as 32-byte splats
  std::uint64_t cells = 0;           // instancing units
  std::uint64_t cellsInstanced = 0;  // units whose section has pools
  double colorErrorSum = 0.0;        // over covered points, largest channel difference
  int colorErrorMax = 0;
  double positionErrorMax = 0.0;  // world units, quantization
  double fftSeconds = 0.0;
  void merge(const InstancingStats& o);
};

// A cell's pools over its quantized voxels, with an explicit palette (tests
// pass the paper's figure 3 translations). Returns the section bytes (without
// pools, every point plain, when no pool forms or pools do not pay; empty for
// no points) and adds to `stats`.
std::vector<std::byte> encodeInstancedCell(std::span<const Splat> points, const QuantizedCell& grid,
                                           std::span<const TranslationCount> palette,
                                           const InstancingOptions& options,
                                           InstancingStats& stats);

// Quantize, palette by FFT, pools, encode.
std::vector<std::byte> instanceCell(std::span<const Splat> points, const InstancingOptions& options,
                                    InstancingStats& stats);

// The instancing units of the top-level cell at `root`: the largest subtrees
// of at most unitPoints points (or leaves), in depth-first order. Their points
// partition the cell's.
std::vector<std::uint32_t> instancingUnits(std::span<const OctreeCell> cells, std::uint32_t root,
                                           std::uint32_t unitPoints);

// Adds the sections of every instancing unit to `content`: instancedRecords
// (per top-level cell its units' sections in depth-first order), the table's
// instancedRecordCount, the cells' pointsOffset, and the extra file
// instanced-sections.bin (common/instanced_section.hpp). On `threads` threads.
// progress(done, total) in points, from the calling thread only; an exception
// it throws stops the workers and propagates.
InstancingStats addInstancedSections(
    DatasetContent& content, const InstancingOptions& options, unsigned threads,
    const std::function<void(std::uint64_t, std::uint64_t)>& progress = {});

}  // namespace pointillist::preprocess
