#include "preprocess/out_of_core.hpp"

#include <fcntl.h>
#include <stdlib.h>  // mkdtemp
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <system_error>
#include <thread>
#include <utility>

#include "common/dataset_writer.hpp"
#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "common/instanced_section.hpp"
#include "preprocess/cube_normals.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/readers.hpp"

namespace pointillist::preprocess {

namespace fs = std::filesystem;

namespace {

constexpr unsigned kSpillDepth = 3;  // at most 512 files open while spilling
// Units no deeper than the Morton sort's radix prefix (8 levels): points that
// share it, sorted together or not at all, stay in one chunk.
constexpr unsigned kMaxUnitDepth = 8;
// While spilling, a block as the reader hands it over and the two sorted
// blocks (points and codes) of the writer: bytes per point of a block.
constexpr std::uint64_t kSpillBytesPerBlockPoint = sizeof(Splat) + 2 * (sizeof(Splat) + 8);
constexpr std::size_t kHandOutPieces = 16;  // a block's pieces handed out on all cores
constexpr std::uint64_t kBaseBytes = std::uint64_t{24} << 20;  // the process, read buffers
constexpr std::uint64_t kCellBytesPerPoint = 4;  // the whole cell array (a cell per ~40 points)
// Estimating normals, besides kBuildBytesPerPoint.
constexpr std::uint64_t kNormalBytesPerPoint = 48;

// The spill directory next to the output; removed with everything in it.
class SpillDir {
 public:
  explicit SpillDir(const fs::path& output) {
    fs::path base = output.lexically_normal();
    if (base.filename().empty()) base = base.parent_path();
    std::string templ = base.string() + ".spill-XXXXXX";
    if (!base.parent_path().empty()) {
      std::error_code ec;
      fs::create_directories(base.parent_path(), ec);
    }
    if (mkdtemp(templ.data()) == nullptr)
      throw Error("cannot create a temporary directory next to '" + base.string() +
                  "': " + std::strerror(errno));
    path_ = templ;
  }
  ~SpillDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  SpillDir(const SpillDir&) = delete;
  SpillDir& operator=(const SpillDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

File openFile(const fs::path& p, const char* mode) {
  File f(std::fopen(p.c_str(), mode));
  if (!f) throw Error("cannot open temporary file " + p.string() + ": " + std::strerror(errno));
  return f;
}

// One spill file: the points of one octree cell, in input order.
struct Bucket {
  unsigned depth = 0;
  std::uint64_t prefix = 0;
  std::uint64_t count = 0;
  fs::path file;
};

std::uint64_t firstCode(unsigned depth, std::uint64_t prefix, unsigned maxDepth) {
  return prefix << (3 * (maxDepth - depth));
}

// Counts points per octree cell at a fixed depth while they stream past (a
// hash map; consecutive points mostly share a cell), which gives the final
// tree's shape down to that depth without building it. Gives up beyond
// `maxCells` cells (a volume rather than surfaces) to stay within the cap.
class ShapeCounter {
 public:
  ShapeCounter(unsigned depth, unsigned maxDepth, std::size_t maxCells)
      : depth_(depth), shift_(3 * (maxDepth - depth)), maxCells_(maxCells) {
    resize(std::size_t{1} << 12);
  }

  void add(std::uint64_t code) {
    if (gaveUp_) return;
    const std::uint64_t key = code >> shift_;
    if (last_ == nullptr || key != lastKey_) {
      last_ = slot(key);
      lastKey_ = key;
      if (last_ == nullptr) {
        gaveUp_ = true;
        keys_ = {};
        counts_ = {};
        return;
      }
    }
    ++*last_;
  }
  bool gaveUp() const { return gaveUp_; }
  unsigned depth() const { return depth_; }
  // Frees the table once the counts are used; counting is over.
  void release() {
    keys_ = {};
    counts_ = {};
    size_ = 0;
    last_ = nullptr;
    gaveUp_ = true;
  }
  // (cell prefix, points) at the counting depth, sorted by prefix.
  std::vector<std::pair<std::uint64_t, std::uint64_t>> sorted() const {
    std::vector<std::pair<std::uint64_t, std::uint64_t>> v;
    v.reserve(size_);
    for (std::size_t i = 0; i < keys_.size(); ++i)
      if (keys_[i] != 0) v.emplace_back(keys_[i] - 1, counts_[i]);
    std::sort(v.begin(), v.end());
    return v;
  }

 private:
  // Open addressing with linear probing (a key is stored plus one: 0 marks a
  // free slot), at most half full: a point of an input in no spatial order
  // costs one probe, where a node-based map cost a division and two misses.
  std::uint64_t* slot(std::uint64_t key) {
    for (std::size_t i = home(key);; i = (i + 1) & mask_) {
      if (keys_[i] == key + 1) return &counts_[i];
      if (keys_[i] != 0) continue;
      if (size_ + 1 > maxCells_) return nullptr;
      if (2 * (size_ + 1) > keys_.size()) {
        resize(2 * keys_.size());
        return slot(key);
      }
      keys_[i] = key + 1;
      ++size_;
      return &counts_[i];
    }
  }
  std::size_t home(std::uint64_t key) const {
    return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> 32) & mask_;
  }
  void resize(std::size_t capacity) {
    std::vector<std::uint64_t> keys(capacity, 0), counts(capacity, 0);
    mask_ = capacity - 1;
    for (std::size_t i = 0; i < keys_.size(); ++i) {
      if (keys_[i] == 0) continue;
      std::size_t j = home(keys_[i] - 1);
      while (keys[j] != 0) j = (j + 1) & mask_;
      keys[j] = keys_[i];
      counts[j] = counts_[i];
    }
    keys_ = std::move(keys);
    counts_ = std::move(counts);
    last_ = nullptr;  // the slots moved
  }

  unsigned depth_;
  unsigned shift_;
  std::size_t maxCells_;
  std::vector<std::uint64_t> keys_, counts_;
  std::size_t mask_ = 0;
  std::size_t size_ = 0;
  std::uint64_t* last_ = nullptr;
  std::uint64_t lastKey_ = 0;
  bool gaveUp_ = false;
};

// The in-memory choice of top-level depth (chooseTopLevelDepth) from the
// counts: exact when the choice falls at or above the counting depth; -1 when
// it needs the tree below (then the chunks' trees are built to find out).
int topLevelDepthFromShape(const ShapeCounter& counter, const OctreeOptions& octree,
                           std::uint64_t pointCount, std::uint64_t targetPacketBytes) {
  if (counter.gaveUp()) return -1;
  const unsigned h = counter.depth();
  std::vector<std::vector<std::pair<std::uint64_t, std::uint64_t>>> level(h + 1);
  level[h] = counter.sorted();
  for (unsigned d = h; d-- > 0;) {
    for (const auto& [key, n] : level[d + 1]) {
      if (!level[d].empty() && level[d].back().first == key >> 3)
        level[d].back().second += n;
      else
        level[d].push_back({key >> 3, n});
    }
  }
  std::vector<std::size_t> atDepth(h + 1, 0), leavesAt(h + 1, 0);
  bool deeper = false;  // a cell at the counting depth splits further
  unsigned treeDepth = 0;
  for (unsigned d = 0; d <= h; ++d) {
    std::size_t parent = 0;
    for (const auto& [key, n] : level[d]) {
      if (d > 0) {
        while (level[d - 1][parent].first != key >> 3) ++parent;
        if (level[d - 1][parent].second <= octree.leafPoints) continue;  // inside a leaf
      }
      ++atDepth[d];
      treeDepth = d;
      const bool leaf = n <= octree.leafPoints || d >= octree.maxDepth;
      if (leaf) ++leavesAt[d];
      if (!leaf && d == h) deeper = true;
    }
  }
  atDepth.resize(treeDepth + 1);
  leavesAt.resize(treeDepth + 1);
  if (deeper) {
    // A stand-in depth below that always satisfies the target: choosing it
    // means the answer lies deeper than the counts reach.
    atDepth.push_back(std::numeric_limits<std::size_t>::max() / 4);
    leavesAt.push_back(0);
  }
  const unsigned chosen = chooseTopLevelDepth(atDepth, leavesAt, pointCount, targetPacketBytes);
  if (deeper && chosen > h) return -1;
  return static_cast<int>(chosen);
}

// A spill file open for appending (POSIX: a cell's run goes in one write).
class SpillFile {
 public:
  explicit SpillFile(fs::path path) : path_(std::move(path)) {
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (fd_ < 0)
      throw Error("cannot open temporary file " + path_.string() + ": " + std::strerror(errno));
  }
  ~SpillFile() {
    if (fd_ >= 0) ::close(fd_);
  }
  SpillFile(const SpillFile&) = delete;
  SpillFile& operator=(const SpillFile&) = delete;

  void append(const void* data, std::size_t bytes) {
    const auto* at = static_cast<const char*>(data);
    while (bytes > 0) {
      const ssize_t wrote = ::write(fd_, at, bytes);
      if (wrote < 0 && errno == EINTR) continue;
      if (wrote <= 0)
        throw Error("cannot write temporary file " + path_.string() + ": " +
                    std::strerror(wrote < 0 ? errno : ENOSPC) + " (is the output's disk full?)");
      at += wrote;
      bytes -= static_cast<std::size_t>(wrote);
    }
  }
  void close() {
    const int fd = std::exchange(fd_, -1);
    if (fd >= 0 && ::close(fd) != 0)
      throw Error("cannot write temporary file " + path_.string() + ": " + std::strerror(errno));
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
  int fd_ = -1;
};

// Writes the points of one cell (parentDepth, parentPrefix) to one file per
// cell at `depth` beneath it. A block is sorted by cell on all cores into one
// of two buffers, and its cells' runs are written on a writing thread while
// the next block is read and sorted: writing from one thread, 8 KiB at a
// time, held the spill of 200 M points at one core (16-30 s, half of it in
// the kernel's write path). Each cell's points keep their input order, so
// the files are the same as from one thread.
class BucketWriter {
 public:
  BucketWriter(const fs::path& dir, unsigned parentDepth, std::uint64_t parentPrefix,
               unsigned depth, const OctreeCube& cube, unsigned maxDepth,
               std::uint64_t& bytesWritten, ShapeCounter* shape = nullptr)
      : dir_(dir),
        depth_(depth),
        base_(parentPrefix << (3 * (depth - parentDepth))),
        morton_(cube, maxDepth),
        maxDepth_(maxDepth),
        bytes_(bytesWritten),
        shape_(shape),
        outs_(std::size_t{1} << (3 * (depth - parentDepth))) {}
  ~BucketWriter() {
    if (writing_.joinable()) writing_.join();
  }
  BucketWriter(const BucketWriter&) = delete;
  BucketWriter& operator=(const BucketWriter&) = delete;

  // Returns once the block is sorted; the caller may reuse its memory.
  void add(std::span<const Splat> splats) {
    const unsigned shift = 3 * (maxDepth_ - depth_);
    const std::size_t n = splats.size();
    const std::size_t cells = outs_.size();
    Sorted& into = sorted_[next_];
    next_ ^= 1u;
    // Pieces of the block on all cores: codes and each piece's count per
    // cell, then each piece's points placed after the pieces before it.
    const std::size_t pieces = std::clamp<std::size_t>(n >> 14, 1, kHandOutPieces);
    const auto pieceBegin = [&](std::size_t p) { return n * p / pieces; };
    into.codes.resize(n);
    into.splats.resize(n);
    pieceCounts_.assign(pieces * cells, 0);
    parallelFor(
        pieces, 0,
        [&](std::size_t p) {
          std::uint32_t* counts = pieceCounts_.data() + p * cells;
          for (std::size_t i = pieceBegin(p); i < pieceBegin(p + 1); ++i) {
            into.codes[i] = morton_(splats[i].position);
            ++counts[(into.codes[i] >> shift) - base_];
          }
        },
        1);
    into.cellFirst.resize(cells + 1);
    std::uint32_t at = 0;
    for (std::size_t c = 0; c < cells; ++c) {
      into.cellFirst[c] = at;
      for (std::size_t p = 0; p < pieces; ++p) {
        std::uint32_t& count = pieceCounts_[p * cells + c];
        const std::uint32_t next = at + count;
        count = at;  // now where the piece's first point of the cell goes
        at = next;
      }
    }
    into.cellFirst[cells] = at;
    parallelFor(
        pieces, 0,
        [&](std::size_t p) {
          std::uint32_t* place = pieceCounts_.data() + p * cells;
          for (std::size_t i = pieceBegin(p); i < pieceBegin(p + 1); ++i)
            into.splats[place[(into.codes[i] >> shift) - base_]++] = splats[i];
        },
        1);
    waitForWriting();
    writing_ = std::thread([this, &into] {
      try {
        write(into);
      } catch (...) {
        writeError_ = std::current_exception();
      }
    });
  }

  std::vector<Bucket> finish() {
    waitForWriting();
    std::vector<Bucket> buckets;
    for (auto& slot : outs_) {
      if (!slot) continue;
      slot->file.close();
      buckets.push_back({depth_, slot->prefix, slot->count, slot->file.path()});
      slot.reset();
    }
    return buckets;
  }

 private:
  struct Sorted {
    std::vector<Splat> splats;         // by cell, in input order within one
    std::vector<std::uint64_t> codes;  // in input order
    std::vector<std::uint32_t> cellFirst;
  };
  struct Out {
    Out(std::uint64_t cellPrefix, fs::path path) : prefix(cellPrefix), file(std::move(path)) {}
    std::uint64_t prefix;
    SpillFile file;
    std::uint64_t count = 0;
  };

  void waitForWriting() {
    if (writing_.joinable()) writing_.join();
    if (writeError_) std::rethrow_exception(std::exchange(writeError_, nullptr));
  }

  // On the writing thread.
  void write(const Sorted& block) {
    // The counts at the counting depth need the codes in input order only.
    if (shape_ != nullptr)
      for (const std::uint64_t code : block.codes) shape_->add(code);
    for (std::size_t c = 0; c + 1 < block.cellFirst.size(); ++c) {
      const std::uint32_t first = block.cellFirst[c], last = block.cellFirst[c + 1];
      if (first == last) continue;
      auto& slot = outs_[c];
      if (!slot) {
        const std::uint64_t prefix = base_ + c;
        slot = std::make_unique<Out>(prefix, dir_ / ("cell-" + std::to_string(depth_) + "-" +
                                                     std::to_string(prefix) + ".bin"));
      }
      slot->file.append(block.splats.data() + first, (last - first) * sizeof(Splat));
      slot->count += last - first;
      bytes_ += (last - first) * sizeof(Splat);
    }
  }

  fs::path dir_;
  unsigned depth_;
  std::uint64_t base_;
  MortonCoder morton_;
  unsigned maxDepth_;
  std::uint64_t& bytes_;
  ShapeCounter* shape_;
  std::vector<std::unique_ptr<Out>> outs_;  // touched by the writing thread only
  std::vector<std::uint32_t> pieceCounts_;
  std::array<Sorted, 2> sorted_;
  unsigned next_ = 0;
  std::thread writing_;
  std::exception_ptr writeError_;
};

// Calls fn(block) over a spill file's points in blocks of at most `block`.
template <class Fn>
void readBucket(const Bucket& b, std::size_t block, Fn fn) {
  File f = openFile(b.file, "rb");
  std::vector<Splat> buffer(std::min<std::uint64_t>(block, std::max<std::uint64_t>(b.count, 1)));
  std::uint64_t left = b.count;
  while (left > 0) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(left, buffer.size()));
    if (std::fread(buffer.data(), sizeof(Splat), n, f.get()) != n)
      throw Error("cannot read temporary file " + b.file.string() + ": short read");
    fn(std::span<const Splat>(buffer.data(), n));
    left -= n;
  }
}

// Reads `count` points from `offset` (points) of spill file `b` into `into`.
void readBucketRange(const Bucket& b, std::uint64_t offset, std::uint64_t count, Splat* into) {
  const int fd = ::open(b.file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0)
    throw Error("cannot open temporary file " + b.file.string() + ": " + std::strerror(errno));
  auto* at = reinterpret_cast<char*>(into);
  std::uint64_t bytes = count * sizeof(Splat);
  auto where = static_cast<off_t>(offset * sizeof(Splat));
  while (bytes > 0) {
    const ssize_t got = ::pread(fd, at, bytes, where);
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) {
      const int error = errno;
      ::close(fd);
      throw Error("cannot read temporary file " + b.file.string() + ": " +
                  (got < 0 ? std::strerror(error) : "short read"));
    }
    at += got;
    where += got;
    bytes -= static_cast<std::uint64_t>(got);
  }
  ::close(fd);
}

// A node of the spill files' tree: a file, or a cell above files.
struct Node {
  std::uint64_t count = 0;
  bool isBucket = false;
};
using NodeKey = std::pair<unsigned, std::uint64_t>;  // depth, prefix

// The final octree above and at the units, in depth-first order.
struct Item {
  bool upper = false;  // an upper cell; else a unit (a whole subtree)
  unsigned depth = 0;
  std::uint64_t prefix = 0;
  std::uint64_t count = 0;
  std::int64_t parent = -1;     // item index
  std::size_t bucketBegin = 0;  // units: their spill files
  std::size_t bucketEnd = 0;
  std::uint32_t globalIndex = kNoIndex;  // in the final cell array
};

struct Layout {
  std::vector<Item> items;
  std::vector<std::vector<std::uint64_t>> splitCells;  // the upper cells by depth
};

// Walks the node tree: a node is a unit when it is a spill file, a leaf of the
// final tree (few points or at max depth), or at the deepest unit depth.
Layout planUnits(const std::map<NodeKey, Node>& nodes, const std::vector<Bucket>& buckets,
                 const OctreeOptions& octree, unsigned unitDepthLimit) {
  Layout layout;
  layout.splitCells.resize(unitDepthLimit + 1);
  std::size_t nextBucket = 0;
  auto walk = [&](auto&& self, unsigned depth, std::uint64_t prefix, std::int64_t parent) -> void {
    const Node& node = nodes.at({depth, prefix});
    Item item;
    item.depth = depth;
    item.prefix = prefix;
    item.count = node.count;
    item.parent = parent;
    const bool split = node.count > octree.leafPoints && depth < octree.maxDepth;
    if (node.isBucket || !split || depth >= unitDepthLimit) {
      // The unit's files: every file under it, consecutive in Morton order.
      item.bucketBegin = nextBucket;
      const unsigned maxDepth = octree.maxDepth;
      const std::uint64_t lo = firstCode(depth, prefix, maxDepth);
      const std::uint64_t hi = firstCode(depth, prefix + 1, maxDepth);
      while (nextBucket < buckets.size()) {
        const std::uint64_t code =
            firstCode(buckets[nextBucket].depth, buckets[nextBucket].prefix, maxDepth);
        if (code < lo || code >= hi) break;
        ++nextBucket;
      }
      item.bucketEnd = nextBucket;
      layout.items.push_back(item);
      return;
    }
    item.upper = true;
    layout.splitCells[depth].push_back(prefix);
    const auto self_index = static_cast<std::int64_t>(layout.items.size());
    layout.items.push_back(item);
    for (std::uint64_t octant = 0; octant < 8; ++octant) {
      const std::uint64_t child = prefix * 8 + octant;
      if (nodes.count({depth + 1, child}) != 0) self(self, depth + 1, child, self_index);
    }
  };
  walk(walk, 0, 0, -1);
  if (nextBucket != buckets.size())
    throw Error("internal error: out-of-core plan left spill files out");
  return layout;
}

std::map<NodeKey, Node> nodeTree(const std::vector<Bucket>& buckets) {
  std::map<NodeKey, Node> nodes;
  for (const Bucket& b : buckets) {
    for (unsigned d = 0; d <= b.depth; ++d)
      nodes[{d, b.prefix >> (3 * (b.depth - d))}].count += b.count;
    nodes[{b.depth, b.prefix}].isBucket = true;
  }
  return nodes;
}

// Consecutive units while their points fit in a chunk.
std::vector<std::pair<std::size_t, std::size_t>> groupChunks(const Layout& layout,
                                                             std::uint64_t capacity) {
  std::vector<std::pair<std::size_t, std::size_t>> chunks;  // item index ranges
  std::uint64_t points = 0;
  for (std::size_t i = 0; i < layout.items.size(); ++i) {
    const Item& it = layout.items[i];
    if (it.upper) continue;
    if (chunks.empty() || points + it.count > capacity) {
      chunks.push_back({i, i + 1});
      points = 0;
    }
    chunks.back().second = i + 1;
    points += it.count;
  }
  return chunks;
}

std::vector<Splat> loadChunk(const Layout& layout, std::pair<std::size_t, std::size_t> chunk,
                             const std::vector<Bucket>& buckets, unsigned threads) {
  // The chunk's files in pieces of at most kPiecePoints, each read to its
  // place on all cores into pages mapped on all cores: read one after
  // another into a fresh array on one thread, a chunk of 27 M points took
  // 0.4-0.9 s (2.4 s for the first, whose pages the process had never
  // touched) while the other core idled.
  constexpr std::uint64_t kPiecePoints = std::uint64_t{1} << 19;  // 16 MiB
  struct Piece {
    const Bucket* bucket;
    std::uint64_t offset, count, into;
  };
  std::vector<Piece> pieces;
  std::uint64_t count = 0;
  for (std::size_t i = chunk.first; i < chunk.second; ++i) {
    const Item& it = layout.items[i];
    if (it.upper) continue;
    for (std::size_t b = it.bucketBegin; b < it.bucketEnd; ++b)
      for (std::uint64_t at = 0; at < buckets[b].count; at += kPiecePoints) {
        const std::uint64_t n = std::min(kPiecePoints, buckets[b].count - at);
        pieces.push_back({&buckets[b], at, n, count});
        count += n;
      }
  }
  std::vector<Splat> points;
  resizePopulated(points, static_cast<std::size_t>(count), threads);
  parallelFor(
      pieces.size(), threads,
      [&](std::size_t p) {
        const Piece& piece = pieces[p];
        readBucketRange(*piece.bucket, piece.offset, piece.count, points.data() + piece.into);
      },
      1);
  return points;
}

// At most this many points of the whole cloud are oriented in memory first
// (out of core, when normals are estimated).
constexpr std::uint64_t kSidePoints = std::uint64_t{1} << 20;

// The sides of normals for the whole cloud, from an even sample of it whose
// normals are estimated and oriented in memory (whole surfaces, so the
// turning rules see them whole). A point of the sample is found again by its
// position: the sample holds points of the cloud itself.
class SideReference {
 public:
  // every: a point is in the sample when inHashSample(s, every).
  SideReference(std::vector<Splat> sample, std::uint64_t every, int neighbours, unsigned threads,
                ProgressFn progress)
      : every_(every) {
    PointCloud cloud;
    cloud.splats = std::move(sample);
    cloud.hasColors = true;
    NormalOptions no;
    no.neighbours = neighbours;
    no.threads = threads;
    no.progress = std::move(progress);
    estimateNormalsAndRadii(cloud, no);
    entries_.reserve(cloud.splats.size());
    for (const Splat& s : cloud.splats)
      entries_.push_back({key(s), {s.normal[0], s.normal[1], s.normal[2]}});
    std::sort(entries_.begin(), entries_.end(),
              [](const Entry& a, const Entry& b) { return a.key < b.key; });
  }
  bool inSample(const Splat& s) const { return inHashSample(s, every_); }
  bool normalOf(const Splat& s, float normal[3]) const {
    if (!inSample(s)) return false;
    const Key k = key(s);
    const auto found = std::lower_bound(entries_.begin(), entries_.end(), k,
                                        [](const Entry& e, const Key& x) { return e.key < x; });
    if (found == entries_.end() || found->key != k) return false;
    std::copy(found->normal.begin(), found->normal.end(), normal);
    return true;
  }

 private:
  using Key = std::array<std::uint32_t, 3>;
  struct Entry {
    Key key;
    std::array<float, 3> normal;
  };
  static Key key(const Splat& s) {
    return {std::bit_cast<std::uint32_t>(s.position[0]),
            std::bit_cast<std::uint32_t>(s.position[1]),
            std::bit_cast<std::uint32_t>(s.position[2])};
  }
  std::uint64_t every_;
  std::vector<Entry> entries_;  // by key
};

// Normals out of core: a chunk's own points alone would give its border
// points one-sided neighbours, and turn each piece of a closed surface by the
// piece's own shape (a piece can come out inside out). So a chunk's points
// within reach of a later chunk's units are handed to that chunk, with their
// final normals and radii, as neighbour anchors (PreprocessOptions): there
// they are neighbours of its border points and pass their side on, as the
// in-memory spanning tree would across the border.
class BorderForwarder {
 public:
  BorderForwarder(const Layout& layout, std::span<const std::pair<std::size_t, std::size_t>> chunks,
                  const OctreeCube& cube, unsigned maxDepth)
      : cube_(cube), maxDepth_(maxDepth), waiting_(chunks.size()) {
    for (std::size_t c = 0; c < chunks.size(); ++c)
      for (std::size_t i = chunks[c].first; i < chunks[c].second; ++i) {
        const Item& it = layout.items[i];
        if (it.upper) continue;
        units_.push_back({firstCode(it.depth, it.prefix, maxDepth),
                          firstCode(it.depth, it.prefix + 1, maxDepth), it.depth, c});
      }
  }

  // The anchors handed to `chunk` so far (all of them, once every chunk
  // before it was forwarded); they are given up.
  std::vector<Splat> take(std::size_t chunk) { return std::move(waiting_[chunk]); }

  // Hands the points of `chunk` (with their normals and radii) that lie
  // within reach of a later chunk to it. Reach: twice the k-th neighbour
  // distance of nearly all of them (r = d_k sqrt(3 / k), normals.hpp), and
  // at least `minReach` (normals from cube moments: two cubes, so the cubes
  // along the border see their whole block).
  void forward(std::size_t chunk, std::span<const Splat> points, int neighbours, double minReach) {
    if (points.empty() || chunk + 1 >= waiting_.size()) return;
    std::vector<float> radii;
    for (std::size_t i = 0; i < points.size(); i += 16) radii.push_back(points[i].radius);
    const auto high = radii.begin() + static_cast<std::ptrdiff_t>(radii.size() * 95 / 100);
    std::nth_element(radii.begin(), high, radii.end());
    const double reach = std::max(minReach, 2.0 * static_cast<double>(*high) *
                                                std::sqrt(static_cast<double>(neighbours) / 3.0));
    if (!(reach > 0.0)) return;
    std::size_t own = kNone;
    std::size_t sentTo[8];
    for (const Splat& p : points) {
      const std::uint64_t code = mortonCode(p.position, cube_, maxDepth_);
      if (own == kNone || code < units_[own].first || code >= units_[own].end) own = unitAt(code);
      if (own == kNone) continue;
      const Unit& u = units_[own];
      // Which faces of its unit it is near, per axis: -1, 0 or +1.
      int near[3];
      const double side = cube_.size / static_cast<double>(std::uint64_t{1} << u.depth);
      bool any = false;
      for (int a = 0; a < 3; ++a) {
        const auto q = compactBits((u.first >> (3 * (maxDepth_ - u.depth))) >> (2 - a));
        const double lo = cube_.min[a] + static_cast<double>(q) * side;
        const double x = static_cast<double>(p.position[a]);
        near[a] = x - lo < reach ? -1 : lo + side - x < reach ? 1 : 0;
        any = any || near[a] != 0;
      }
      if (!any) continue;
      std::size_t sent = 0;
      // Every combination of the near faces: across faces, edges, corners.
      for (int mask = 1; mask < 8; ++mask) {
        float probe[3];
        bool valid = true;
        for (int a = 0; a < 3; ++a) {
          const bool use = (mask >> a & 1) != 0;
          if (use && near[a] == 0) valid = false;
          probe[a] = p.position[a] + (use ? static_cast<float>(near[a] * reach) : 0.0f);
          if (static_cast<double>(probe[a]) < cube_.min[a] ||
              static_cast<double>(probe[a]) >= cube_.min[a] + cube_.size)
            valid = false;
        }
        if (!valid) continue;
        const std::size_t other = unitAt(mortonCode(probe, cube_, maxDepth_));
        if (other == kNone || units_[other].chunk <= chunk) continue;
        const std::size_t to = units_[other].chunk;
        if (std::find(sentTo, sentTo + sent, to) != sentTo + sent) continue;
        sentTo[sent++] = to;
        waiting_[to].push_back(p);
      }
    }
  }

 private:
  static constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
  struct Unit {
    std::uint64_t first, end;  // its Morton codes at the finest depth
    unsigned depth;
    std::size_t chunk;
  };
  std::size_t unitAt(std::uint64_t code) const {
    const auto after = std::upper_bound(units_.begin(), units_.end(), code,
                                        [](std::uint64_t c, const Unit& u) { return c < u.first; });
    if (after == units_.begin()) return kNone;
    const auto at = static_cast<std::size_t>(after - units_.begin()) - 1;
    return code < units_[at].end ? at : kNone;
  }

  OctreeCube cube_;
  unsigned maxDepth_;
  std::vector<Unit> units_;  // in Morton order
  std::vector<std::vector<Splat>> waiting_;
};

OctreeFrame frameOf(const OctreeCube& cube, const Layout& layout) {
  OctreeFrame frame;
  frame.cube = cube;
  frame.splitCells = layout.splitCells;
  return frame;
}

// Per-cell summary of what a parent merges (as assembleDatasetContent does).
struct Merged {
  float lo[3] = {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
                 std::numeric_limits<float>::infinity()};
  float hi[3] = {-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                 -std::numeric_limits<float>::infinity()};
  float maxRadius = 0.0f;
  CellNormals normals;
  unsigned level = 0;
  unsigned children = 0;
};

// Test hook: POINTILLIST_PREPROCESS_FAIL_AFTER_CHUNKS=N fails the run once N
// chunks are built, so tests can show that a failure midway leaves nothing.
void failForTestAfter(std::uint64_t builtChunks) {
  static const char* const text = std::getenv("POINTILLIST_PREPROCESS_FAIL_AFTER_CHUNKS");
  if (text != nullptr && std::to_string(builtChunks) == text)
    throw Error("failing on purpose after " + std::to_string(builtChunks) +
                " chunk(s) (POINTILLIST_PREPROCESS_FAIL_AFTER_CHUNKS)");
}

}  // namespace

std::size_t spillBlockPoints(std::uint64_t memoryBytes) {
  // A 64th of the cap (a small cap keeps its room for the chunks), and no
  // more than the reader's usual block: larger ones gained nothing.
  return static_cast<std::size_t>(std::clamp<std::uint64_t>(
      memoryBytes / 64 / kSpillBytesPerBlockPoint, 4096, std::uint64_t{1} << 18));
}

std::uint64_t chunkCapacity(std::uint64_t memoryBytes, std::uint64_t pointCount,
                            bool estimateNormals) {
  const std::uint64_t spillBuffers = spillBlockPoints(memoryBytes) * kSpillBytesPerBlockPoint;
  const std::uint64_t fixed = kBaseBytes + spillBuffers + pointCount * kCellBytesPerPoint;
  if (memoryBytes <= fixed) return 0;
  // A chunk whose normals are estimated costs more a point: its moments and
  // neighbours, and the points it borrows across its borders (about 175
  // bytes a chunk point for a 400 k scan under --memory-mb 40; the 4 MiB the
  // spill once kept for its file buffers had hidden the difference).
  return (memoryBytes - fixed) /
         (kBuildBytesPerPoint + (estimateNormals ? kNormalBytesPerPoint : 0));
}

std::uint64_t inMemoryBytes(std::uint64_t pointCount) {
  return kBaseBytes + pointCount * (kBuildBytesPerPoint + kCellBytesPerPoint);
}

bool fitsInMemory(std::uint64_t memoryBytes, std::uint64_t pointCount) {
  return memoryBytes > kBaseBytes &&
         pointCount <= (memoryBytes - kBaseBytes) / (kBuildBytesPerPoint + kCellBytesPerPoint);
}

OutOfCoreResult preprocessOutOfCore(const std::vector<fs::path>& inputs, const fs::path& output,
                                    const OutOfCoreOptions& options,
                                    const StageProgressFn& progress) {
  OctreeOptions octree = options.build.octree;
  octree.threads = options.build.threads;
  if (octree.maxDepth < 1 || octree.maxDepth > 21)
    throw UsageError("octree max depth must be 1..21, got " + std::to_string(octree.maxDepth));
  auto report = [&](const char* stage, std::uint64_t done, std::uint64_t total) {
    if (progress) progress(stage, done, total);
  };
  OutOfCoreResult result;
  // The dataset writer first: a bad output fails before any reading.
  DatasetWriter writer(output, options.overwrite);
  SpillDir spill(output);

  // 1. Bounds.
  ReadOptions read = options.read;
  read.sinkBlock = std::min(read.sinkBlock, spillBlockPoints(options.memoryBytes));
  read.progress = [&](std::uint64_t done, std::uint64_t total) { report("bounds", done, total); };
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::numeric_limits<double>::infinity();
    hi[a] = -std::numeric_limits<double>::infinity();
  }
  std::uint64_t count = 0;
  const PointCloud flags = streamPointClouds(
      inputs, read,
      [&](std::span<const Splat> block) {
        for (const Splat& s : block)
          for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], static_cast<double>(s.position[a]));
            hi[a] = std::max(hi[a], static_cast<double>(s.position[a]));
          }
      },
      count);
  if (count >= kNoIndex)
    throw InputError("too many points (" + std::to_string(count) + "); at most " +
                     std::to_string(kNoIndex - 1));
  result.points = count;
  const OctreeCube cube = boundingCube(lo, hi);
  const bool estimateNormals = !flags.hasNormals || (!flags.hasRadii && options.knnRadii);
  std::uint64_t capacity = chunkCapacity(options.memoryBytes, count, estimateNormals);
  // Estimating normals keeps a side reference (below) while chunks are built:
  // an even sample of a quarter of a chunk, but at least one point in 64 up
  // to 64 Ki points (sparser ones lose thin parts), at most kSidePoints; 24
  // bytes a point.
  const std::uint64_t sampleSize =
      estimateNormals
          ? std::min({kSidePoints, count,
                      std::max(capacity / 4, std::min<std::uint64_t>(65536, count / 64))})
          : 0;
  capacity -= std::min(capacity, sampleSize * 24 / kBuildBytesPerPoint);
  if (capacity < std::uint64_t{octree.leafPoints} * 8)
    throw UsageError("--memory-mb " + std::to_string(options.memoryBytes >> 20) +
                     " is too small for " + std::to_string(count) +
                     " points: the run itself needs "
                     "about " +
                     std::to_string((options.memoryBytes - capacity * kBuildBytesPerPoint +
                                     std::uint64_t{octree.leafPoints} * 8 * kBuildBytesPerPoint) >>
                                    20) +
                     " MiB");
  result.chunkCapacity = capacity;

  // Normals to estimate: an even sample of the whole cloud, oriented in
  // memory before the chunks, tells each chunk the side its pieces take
  // (SideReference), as the in-memory run decides it for whole surfaces.
  std::vector<Splat> sample;
  const std::uint64_t sampleEvery = sampleSize > 0 ? (count + sampleSize - 1) / sampleSize : 0;
  // Normals from cube moments: the lattice from its own sample, as the
  // in-memory run chooses it (the same points, the same cubes).
  const NormalMethod normalMethod = resolveNormalMethod(options.build.normalMethod, count);
  const bool momentNormals = estimateNormals && normalMethod == NormalMethod::Moments &&
                             !(options.build.cubeLattice.side > 0.0);
  std::vector<Splat> latticeSample;
  const std::uint64_t latticeEvery = momentNormals ? latticeSampleEvery(count) : 0;

  // 2. Spilling, then splitting files that hold more than a chunk.
  read.progress = [&](std::uint64_t done, std::uint64_t total) { report("spilling", done, total); };
  const unsigned spillDepth = std::min(kSpillDepth, octree.maxDepth);
  std::vector<Bucket> buckets;
  ShapeCounter shape(
      std::min(kMaxUnitDepth, octree.maxDepth), octree.maxDepth,
      options.shapeCellLimit > 0
          ? options.shapeCellLimit
          : std::max<std::size_t>(std::size_t{1} << 16, options.memoryBytes / 16 / 64));
  {
    BucketWriter writer0(spill.path(), 0, 0, spillDepth, cube, octree.maxDepth, result.spillBytes,
                         options.build.topLevelDepth < 0 ? &shape : nullptr);
    std::uint64_t again = 0;
    streamPointClouds(
        inputs, read,
        [&](std::span<const Splat> block) {
          writer0.add(block);
          if (sampleEvery > 0) appendHashSample(block, sampleEvery, sample);
          if (latticeEvery > 0) appendHashSample(block, latticeEvery, latticeSample);
        },
        again);
    if (again != count)
      throw InputError("the input changed while it was read: " + std::to_string(count) +
                       " points, then " + std::to_string(again));
    buckets = writer0.finish();
  }
  const std::size_t ioBlock = std::max<std::size_t>(
      4096, static_cast<std::size_t>(std::min<std::uint64_t>(capacity / 16, 1u << 18)));
  const unsigned deepest = std::min(kMaxUnitDepth, octree.maxDepth);
  for (bool again = true; again;) {
    again = false;
    std::vector<Bucket> next;
    for (Bucket& b : buckets) {
      if (b.count <= capacity || b.depth >= deepest) {
        next.push_back(std::move(b));
        continue;
      }
      BucketWriter split(spill.path(), b.depth, b.prefix, b.depth + 1, cube, octree.maxDepth,
                         result.spillBytes);
      std::uint64_t moved = 0;
      readBucket(b, ioBlock, [&](std::span<const Splat> block) {
        split.add(block);
        moved += block.size();
        report("splitting spill files", moved, b.count);
      });
      fs::remove(b.file);
      for (Bucket& c : split.finish()) next.push_back(std::move(c));
      again = true;
    }
    buckets = std::move(next);
  }
  std::sort(buckets.begin(), buckets.end(), [&](const Bucket& a, const Bucket& b) {
    return firstCode(a.depth, a.prefix, octree.maxDepth) <
           firstCode(b.depth, b.prefix, octree.maxDepth);
  });
  result.spillFiles = buckets.size();
  const std::map<NodeKey, Node> nodes = nodeTree(buckets);

  // 3-4. Units, and the top-level depth.
  PreprocessOptions build = options.build;
  build.normalMethod = normalMethod;  // the whole cloud's choice, not a chunk's
  if (momentNormals)
    build.cubeLattice =
        chooseCubeLattice(latticeSample, latticeEvery, cube.min, cube.size, build.cubePoints);
  const double minReach =
      build.normalMethod == NormalMethod::Moments ? 2.0 * build.cubeLattice.side : 0.0;
  Layout layout = planUnits(nodes, buckets, octree,
                            build.topLevelDepth >= 0
                                ? std::min<unsigned>(deepest, unsigned(build.topLevelDepth))
                                : deepest);
  if (build.topLevelDepth < 0 && groupChunks(layout, capacity).size() > 1) {
    const int fromShape = topLevelDepthFromShape(shape, octree, count, build.targetPacketBytes);
    result.shapeCounted = fromShape >= 0;
    if (fromShape >= 0) {
      build.topLevelDepth = fromShape;
      layout = planUnits(nodes, buckets, octree,
                         std::min<unsigned>(deepest, unsigned(build.topLevelDepth)));
    }
  }
  shape.release();  // its table would otherwise stay through the chunks' builds
  if (build.topLevelDepth < 0 && groupChunks(layout, capacity).size() > 1) {
    std::vector<std::size_t> atDepth(octree.maxDepth + 1, 0), leavesAt(octree.maxDepth + 1, 0);
    unsigned treeDepth = 0;
    for (const Item& it : layout.items) {
      if (!it.upper) continue;
      ++atDepth[it.depth];
      treeDepth = std::max(treeDepth, it.depth);
    }
    const OctreeFrame frame = frameOf(cube, layout);
    std::uint64_t done = 0;
    for (const auto& chunk : groupChunks(layout, capacity)) {
      report("structure", done, count);
      std::vector<Splat> points = loadChunk(layout, chunk, buckets, options.build.threads);
      const std::uint64_t n = points.size();
      const Octree tree = buildOctree(std::move(points), octree, {}, &frame);
      std::size_t unit = chunk.first;
      for (std::size_t i = 0; i < tree.cells.size();) {
        const BuildCell& c = tree.cells[i];
        while (unit < chunk.second && layout.items[unit].upper) ++unit;
        const std::uint64_t prefix =
            mortonCode(tree.points[c.begin].position, cube, octree.maxDepth) >>
            (3 * (octree.maxDepth - c.depth));
        if (unit < chunk.second && c.depth == layout.items[unit].depth &&
            prefix == layout.items[unit].prefix) {
          const std::size_t end = c.nextSibling == kNoIndex ? tree.cells.size() : c.nextSibling;
          for (std::size_t j = i; j < end; ++j) {
            ++atDepth[tree.cells[j].depth];
            if (tree.cells[j].isLeaf()) ++leavesAt[tree.cells[j].depth];
            treeDepth = std::max<unsigned>(treeDepth, tree.cells[j].depth);
          }
          ++unit;
          i = end;
        } else {
          ++i;  // an upper cell, counted above
        }
      }
      done += n;
    }
    report("structure", count, count);
    atDepth.resize(treeDepth + 1);
    leavesAt.resize(treeDepth + 1);
    build.topLevelDepth =
        static_cast<int>(chooseTopLevelDepth(atDepth, leavesAt, count, build.targetPacketBytes));
    layout = planUnits(nodes, buckets, octree,
                       std::min<unsigned>(deepest, unsigned(build.topLevelDepth)));
  }

  // 5. Building chunk by chunk; the packets go straight to the writer.
  const OctreeFrame frame = frameOf(cube, layout);
  const auto chunks = groupChunks(layout, capacity);
  result.chunks = chunks.size();
  DatasetContent content;
  std::vector<InstancedCellSection> sectionsPerCell;  // --instanced, by global cell
  std::vector<Merged> merged(layout.items.size());
  build.radiiInLeaves = flags.hasNormals && !flags.hasRadii && !options.knnRadii;
  build.estimateNormals = estimateNormals;
  build.radiusNeighbours = options.neighbours;
  std::uint64_t done = 0;
  std::uint64_t builtChunks = 0;
  std::size_t nextItem = 0;
  unsigned treeDepth = 0;
  std::optional<BorderForwarder> borders;
  std::optional<SideReference> sides;
  if (estimateNormals && !sample.empty()) {
    sides.emplace(std::move(sample), sampleEvery, options.neighbours, build.threads,
                  [&](std::uint64_t sampled, std::uint64_t total) {
                    report("normals of a sample", sampled, total);
                  });
    build.sideReference = [&](const Splat& s, float normal[3]) {
      return sides->normalOf(s, normal);
    };
  }
  if (estimateNormals) borders.emplace(layout, chunks, cube, octree.maxDepth);
  // Without the stages that add to packets, a chunk's packets are written as
  // their level-splats are made, as in memory: written after the chunk, its
  // gigabyte of packets held both cores idle for 2 s a chunk on this VM.
  const bool streamPackets = !build.instancing && !build.statistical;
  if (streamPackets)
    build.packetSink = [&](std::span<const Splat> levelSplats, std::span<const Splat> points) {
      writer.appendPacket(levelSplats, {}, points);
    };
  // A chunk's spill files are removed once it is loaded, on a thread of their
  // own while the chunk is built: at the end they took seconds to free (6 GiB
  // for 200 M points), and the disk is freed as the run goes. Declared after
  // the spill directory, so it is joined before the directory goes.
  std::jthread remover;
  for (std::size_t chunkIndex = 0; chunkIndex < chunks.size(); ++chunkIndex) {
    const auto& chunk = chunks[chunkIndex];
    std::vector<Splat> points = loadChunk(layout, chunk, buckets, options.build.threads);
    if (remover.joinable()) remover.join();
    std::vector<fs::path> loaded;
    for (std::size_t i = chunk.first; i < chunk.second; ++i)
      if (!layout.items[i].upper)
        for (std::size_t b = layout.items[i].bucketBegin; b < layout.items[i].bucketEnd; ++b)
          loaded.push_back(buckets[b].file);
    remover = std::jthread([files = std::move(loaded)] {
      for (const fs::path& file : files) {
        std::error_code ignored;  // what is left goes with the directory
        fs::remove(file, ignored);
      }
    });
    const std::uint64_t n = points.size();
    result.largestChunkPoints = std::max(result.largestChunkPoints, n);
    if (n > capacity) result.capExceeded = true;
    // The chunk's stages in order, weighted by their usual share of its time,
    // so the bar only moves forward.
    auto inner = [&](const char* stage, std::uint64_t d, std::uint64_t t) {
      struct Share {
        const char* stage;
        double weight;
      };
      const Share shares[] = {
          {"octree", 0.15}, {"normals and radii", build.estimateNormals ? 1.0 : 0.0},
          {"radii", 0.05},  {"level-splats", 0.65},
          {"cells", 0.15},  {"instancing", build.instancing ? 0.5 : 0.0}};
      double before = 0.0, total = 0.0, weight = 0.0;
      bool seen = false;
      for (const Share& sh : shares) {
        if (std::strcmp(sh.stage, stage) == 0) {
          seen = true;
          weight = sh.weight;
        } else if (!seen) {
          before += sh.weight;
        }
        total += sh.weight;
      }
      if (!seen) return;
      const double within =
          t > 0 ? static_cast<double>(std::min(d, t)) / static_cast<double>(t) : 0;
      report("building",
             done + static_cast<std::uint64_t>(static_cast<double>(n) * (before + weight * within) /
                                               total),
             count);
    };
    std::vector<CellNormals> normals;
    const std::vector<Splat> anchors = borders ? borders->take(chunkIndex) : std::vector<Splat>{};
    build.neighbourAnchors = anchors;
    DatasetContent local = buildDatasetContent(std::move(points), build, inner, &frame, &normals);
    build.neighbourAnchors = {};
    if (borders) borders->forward(chunkIndex, local.points, options.neighbours, minReach);

    // The chunk's units, in order, each a subtree of the local tree.
    const auto localCount = static_cast<std::uint32_t>(local.cells.size());
    std::vector<std::uint32_t> toGlobal(localCount, kNoIndex);
    std::size_t unit = chunk.first;
    for (std::uint32_t i = 0; i < localCount;) {
      const OctreeCell& c = local.cells[i];
      while (unit < chunk.second && layout.items[unit].upper) ++unit;
      const std::uint64_t prefix =
          mortonCode(c.boundsMin, cube, octree.maxDepth) >> (3 * (octree.maxDepth - c.depth));
      if (unit >= chunk.second || c.depth != layout.items[unit].depth ||
          prefix != layout.items[unit].prefix) {
        ++i;  // a cell above the units: merged below
        continue;
      }
      // Upper cells before this unit in depth-first order come first.
      for (; nextItem < unit; ++nextItem) {
        Item& up = layout.items[nextItem];
        if (!up.upper) throw Error("internal error: out-of-core unit out of order");
        up.globalIndex = static_cast<std::uint32_t>(content.cells.size());
        OctreeCell cell{};
        cell.depth = static_cast<std::uint8_t>(up.depth);
        cell.topLevel = kNoIndex;
        content.cells.push_back(cell);
      }
      Item& it = layout.items[unit];
      it.globalIndex = static_cast<std::uint32_t>(content.cells.size());
      const std::uint32_t end = c.nextSibling == kNoIndex ? localCount : c.nextSibling;
      for (std::uint32_t j = i; j < end; ++j) {
        toGlobal[j] = static_cast<std::uint32_t>(content.cells.size());
        content.cells.push_back(local.cells[j]);
        treeDepth = std::max<unsigned>(treeDepth, local.cells[j].depth);
      }
      Merged& m = merged[unit];
      for (int a = 0; a < 3; ++a) {
        m.lo[a] = c.boundsMin[a];
        m.hi[a] = c.boundsMax[a];
      }
      m.maxRadius = c.maxSplatRadius;
      m.normals = normals[i];
      m.level = c.level;
      nextItem = unit + 1;
      ++unit;
      i = end;
    }
    while (unit < chunk.second && layout.items[unit].upper) ++unit;
    if (unit != chunk.second) throw Error("internal error: out-of-core chunk lost a unit");

    // Its top-level cells and packets, renumbered.
    const auto topBase = static_cast<std::uint32_t>(content.topLevel.size());
    std::uint64_t p = 0, s = 0, r = 0;
    for (const TopLevelCell& t : local.topLevel) {
      TopLevelCell g = t;
      g.cellIndex = toGlobal[t.cellIndex];
      if (g.cellIndex == kNoIndex)
        throw Error("internal error: a top-level cell lies above the out-of-core units");
      content.topLevel.push_back(g);
      if (!streamPackets)
        writer.appendPacket(
            std::span<const Splat>(local.levelSplats).subspan(s, t.levelSplatCount),
            std::span<const Splat>(local.instancedRecords).subspan(r, t.instancedRecordCount),
            std::span<const Splat>(local.points).subspan(p, t.pointCount));
      p += t.pointCount;
      s += t.levelSplatCount;
      r += t.instancedRecordCount;
    }
    for (std::uint32_t j = 0; j < localCount; ++j) {
      if (toGlobal[j] == kNoIndex) continue;
      OctreeCell& g = content.cells[toGlobal[j]];
      if (g.topLevel != kNoIndex) g.topLevel += topBase;
    }
    // --instanced: the units' sections, renumbered (offsets are within packets).
    for (const auto& file : local.extraFiles) {
      if (file.key != kInstancedSectionsKey) continue;
      if (file.bytes.size() != std::size_t{localCount} * sizeof(InstancedCellSection))
        throw Error("internal error: an out-of-core chunk's instanced sections table");
      sectionsPerCell.resize(content.cells.size());
      for (std::uint32_t j = 0; j < localCount; ++j)
        if (toGlobal[j] != kNoIndex)
          std::memcpy(&sectionsPerCell[toGlobal[j]],
                      file.bytes.data() + j * sizeof(InstancedCellSection),
                      sizeof(InstancedCellSection));
    }
    if (content.manifest.source.empty()) content.manifest = local.manifest;
    done += n;
    report("building", done, count);
    failForTestAfter(++builtChunks);
  }
  for (; nextItem < layout.items.size(); ++nextItem)
    if (!layout.items[nextItem].upper) throw Error("internal error: out-of-core unit not built");

  // 6. The cells above the units. nextSibling: the first later cell that is
  // not deeper (as buildOctree).
  auto& cells = content.cells;
  linkNextSiblings(std::span<OctreeCell>(cells));
  // Children merge into their parent from the back, as in memory.
  for (std::size_t k = layout.items.size(); k-- > 0;) {
    const Item& it = layout.items[k];
    if (it.parent < 0) continue;
    const Merged& from = merged[k];
    Merged& into = merged[static_cast<std::size_t>(it.parent)];
    for (int a = 0; a < 3; ++a) {
      into.lo[a] = std::min(into.lo[a], from.lo[a]);
      into.hi[a] = std::max(into.hi[a], from.hi[a]);
    }
    into.maxRadius = std::max(into.maxRadius, from.maxRadius);
    into.normals.sum = add(into.normals.sum, from.normals.sum);
    into.normals.unknown = into.normals.unknown || from.normals.unknown;
    into.level = std::max(into.level, from.level + 1);
    ++into.children;
  }
  for (std::size_t k = layout.items.size(); k-- > 0;) {
    const Item& it = layout.items[k];
    if (!it.upper) continue;
    const Merged& m = merged[k];
    OctreeCell& c = cells[it.globalIndex];
    for (int a = 0; a < 3; ++a) {
      c.boundsMin[a] = m.lo[a];
      c.boundsMax[a] = m.hi[a];
    }
    c.maxSplatRadius = m.maxRadius;
    c.level = static_cast<std::uint8_t>(m.level);
    c.childCount = static_cast<std::uint8_t>(m.children);
    c.flags = 0;
    mergeChildCones(cells, it.globalIndex, m.normals);
  }

  DatasetManifest& manifest = content.manifest;
  manifest.source = flags.source;
  manifest.createdBy = options.createdBy.empty() ? manifest.createdBy : options.createdBy;
  // (One chunk with the depth left open: the chunk chose it, as in memory.)
  if (build.topLevelDepth >= 0)
    manifest.topLevelDepth =
        std::min<unsigned>(treeDepth, static_cast<unsigned>(build.topLevelDepth));
  manifest.maxDepth = octree.maxDepth;
  manifest.leafPoints = octree.leafPoints;
  manifest.levelSplatReduction = build.levelSplats.reduction;
  if (build.instancing) {
    sectionsPerCell.resize(cells.size());
    DatasetContent::ExtraFile file{kInstancedSectionsKey, kInstancedSectionsName, {}};
    file.bytes.resize(sectionsPerCell.size() * sizeof(InstancedCellSection));
    std::memcpy(file.bytes.data(), sectionsPerCell.data(), file.bytes.size());
    content.extraFiles.push_back(std::move(file));
  }
  report("writing", 0, 1);
  result.bytesWritten = writer.commit(content);
  report("writing", 1, 1);
  result.manifest = content.manifest;
  return result;
}

}  // namespace pointillist::preprocess
