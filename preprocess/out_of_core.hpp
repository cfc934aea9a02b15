#pragma once
// The out-of-core preprocess: inputs bigger than the memory cap stream through
// temporary files next to the output, chunked by space, and each chunk is
// built in memory as an in-memory run builds the whole cloud.
//
//  1. bounds: one pass over the input gives the octree's cube;
//  2. spilling: a second pass writes every point to the file of its octree cell
//     at depth 3 (at most 512 files); a file holding more than a chunk may is
//     split again one level down (at most to depth 8);
//  3. units: the cells that the whole cloud splits above the files are the
//     upper cells; below them each file (or a leaf above several) is a unit, a
//     whole subtree of the final octree. Units at most as deep as the top-level
//     depth, so a top-level cell (a packet) never spans two chunks;
//  4. the top-level depth, when chosen automatically and there is more than one
//     chunk: as in memory, from the tree's shape, known down to depth 8 from
//     counts taken while spilling; only when the choice lies deeper (or the
//     counts grew too many) is each chunk's octree built once to find it;
//  5. building: consecutive units up to the cap form a chunk, built with
//     buildDatasetContent in the whole cloud's frame (its cube, its upper cells
//     split); the units' cells and packets go straight into the dataset writer;
//  6. the upper cells are merged from their children (bounds, radius, normal
//     sums in the in-memory order, cones from the children's cones).
//
// For input with normals the dataset equals the in-memory run's bit for bit.
// Input without normals gets them estimated chunk by chunk: a point at a chunk's
// face sees only its own side's neighbours there.
//
// Temporary files: `<output>.spill-XXXXXX/`, removed on success, on any
// failure, and on an interrupt (the caller's progress callback throws).
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "common/dataset_manifest.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

// Memory a point costs while its chunk is built in memory: the point, its sort
// keys and the reordered copy in the octree build, level-splats and the
// assembled packets (measured peak about 100 bytes; rounded up).
inline constexpr std::uint64_t kBuildBytesPerPoint = 128;

// Points one chunk may hold under `memoryBytes` for a cloud of `pointCount`
// points (what the whole run keeps besides a chunk is taken off first), whose
// normals are estimated or not; 0 when the cap is too small to work at all.
std::uint64_t chunkCapacity(std::uint64_t memoryBytes, std::uint64_t pointCount,
                            bool estimateNormals = false);

// Points in a block of the spill under `memoryBytes` (the reader's block; the
// writer keeps two sorted ones besides).
std::size_t spillBlockPoints(std::uint64_t memoryBytes);

// Memory a whole cloud of `pointCount` points needs when built in memory.
std::uint64_t inMemoryBytes(std::uint64_t pointCount);

// True when a cloud of `pointCount` points fits in memory whole under the cap.
bool fitsInMemory(std::uint64_t memoryBytes, std::uint64_t pointCount);

struct OutOfCoreOptions {
  PreprocessOptions build;  // octree, level-splats, top-level depth, threads
  ReadOptions read;         // mesh sampling, non-finite policy, progress unused
  std::uint64_t memoryBytes = std::uint64_t{4096} << 20;
  int neighbours = 12;    // normals and radii where the input has none
  bool knnRadii = false;  // radii by neighbour search even when normals are given
  bool overwrite = false;
  std::string createdBy;
  // Cells the spill pass counts for the tree's shape before it gives up and
  // the structure pass builds the chunks' trees instead (0: by the cap).
  std::size_t shapeCellLimit = 0;
};

struct OutOfCoreResult {
  DatasetManifest manifest;
  std::uint64_t bytesWritten = 0;
  std::uint64_t points = 0;
  std::uint64_t chunks = 0;
  std::uint64_t largestChunkPoints = 0;
  std::uint64_t chunkCapacity = 0;
  std::uint64_t spillFiles = 0;
  std::uint64_t spillBytes = 0;  // written to temporary files, re-spills included
  bool capExceeded = false;      // one top-level cell alone held more than a chunk may
  bool shapeCounted = false;     // the top-level depth came from counts taken while spilling
};

// stage names: "bounds", "spilling" (bytes of input), "structure", "building"
// (points). The callback may throw to stop (temporary files are removed).
OutOfCoreResult preprocessOutOfCore(const std::vector<std::filesystem::path>& inputs,
                                    const std::filesystem::path& output,
                                    const OutOfCoreOptions& options,
                                    const StageProgressFn& progress);

}  // namespace pointillist::preprocess
