#include "preprocess/instancing.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <numbers>
#include <thread>

#include "common/errors.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

// ---- the vertex-transformation table ------------------------------------

constexpr std::size_t kWords = 4;  // 256 palette entries
using Column = std::array<std::uint64_t, kWords>;

int popcount(const Column& c) {
  int n = 0;
  for (const std::uint64_t w : c) n += std::popcount(w);
  return n;
}

struct Occupancy {
  std::array<std::int32_t, 3> dims{};
  std::vector<std::int32_t> index;  // voxel -> distinct voxel number, or -1

  void reset(const std::array<std::int32_t, 3>& d) {
    dims = d;
    index.assign(gridVolume(d), -1);
  }
  std::int32_t at(std::int32_t x, std::int32_t y, std::int32_t z) const {
    if (x < 0 || y < 0 || z < 0 || x >= dims[0] || y >= dims[1] || z >= dims[2]) return -1;
    return index[gridIndex(dims, x, y, z)];
  }
  std::int32_t& slot(const Voxel& v) { return index[gridIndex(dims, v.q[0], v.q[1], v.q[2])]; }
};

bool knownNormal(const Splat& s) {
  return s.normal[0] * s.normal[0] + s.normal[1] * s.normal[1] + s.normal[2] * s.normal[2] > 0.25f;
}

int colorDifference(const Splat& a, const Splat& b) {
  int d = 0;
  for (int c = 0; c < 4; ++c) d = std::max(d, std::abs(int{a.color[c]} - int{b.color[c]}));
  return d;
}

template <typename T>
void appendBytes(std::vector<std::byte>& out, const T& value) {
  const auto* p = reinterpret_cast<const std::byte*>(&value);
  out.insert(out.end(), p, p + sizeof(T));
}

void padTo(std::vector<std::byte>& out, std::size_t multiple) {
  out.resize((out.size() + multiple - 1) / multiple * multiple, std::byte{0});
}

}  // namespace

// ---- quantization ---------------------------------------------------------

QuantizedCell quantizeCell(std::span<const Splat> points, const InstancingOptions& options) {
  QuantizedCell out;
  if (points.empty()) return out;
  const unsigned maxBits = std::clamp(options.maxBits, 1u, 15u);
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = points[0].position[a];
  std::vector<float> radii(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double{points[i].position[a]});
      hi[a] = std::max(hi[a], double{points[i].position[a]});
    }
    radii[i] = points[i].radius;
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  const auto middle = radii.begin() + static_cast<std::ptrdiff_t>(radii.size() / 2);
  std::nth_element(radii.begin(), middle, radii.end());
  const double medianRadius = *middle;
  const double finest = extent / double((1u << maxBits) - 1);
  double step = options.stepShare * medianRadius;
  if (!(step > finest)) step = finest;  // also when the radius is unknown
  if (!(step > 0.0)) step = 1.0;        // a single voxel
  out.step = static_cast<float>(step);
  const auto steps = static_cast<std::uint64_t>(std::llround(extent / double{out.step}));
  out.bits = std::clamp(static_cast<unsigned>(std::bit_width(steps)), 1u, maxBits);
  const std::int32_t last = static_cast<std::int32_t>((1u << out.bits) - 1);
  for (int a = 0; a < 3; ++a) {
    out.origin[static_cast<std::size_t>(a)] = static_cast<float>(lo[a]);
    out.high[static_cast<std::size_t>(a)] = static_cast<float>(hi[a]);
  }
  out.dims = {1, 1, 1};
  out.voxels.resize(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (std::size_t a = 0; a < 3; ++a) {
      const double d = (double{points[i].position[a]} - double{out.origin[a]}) / double{out.step};
      const auto q = std::clamp(static_cast<std::int32_t>(std::lround(d)), 0, last);
      out.voxels[i].q[a] = q;
      out.dims[a] = std::max(out.dims[a], q + 1);
    }
  }
  return out;
}

void InstancingStats::merge(const InstancingStats& o) {
  points += o.points;
  covered += o.covered;
  pools += o.pools;
  vertices += o.vertices;
  translations += o.translations;
  vertexBytes += o.vertexBytes;
  translationBytes += o.translationBytes;
  tagBytes += o.tagBytes;
  sectionBytes += o.sectionBytes;
  plainBytes += o.plainBytes;
  cells += o.cells;
  cellsInstanced += o.cellsInstanced;
  colorErrorSum += o.colorErrorSum;
  colorErrorMax = std::max(colorErrorMax, o.colorErrorMax);
  positionErrorMax = std::max(positionErrorMax, o.positionErrorMax);
  fftSeconds += o.fftSeconds;
}

// ---- pools ----------------------------------------------------------------

namespace {

// A section's header for the unit's grid; counts and offsets are the caller's.
InstancedHeader sectionHeader(const QuantizedCell& grid) {
  InstancedHeader h{};
  h.magic = kInstancedMagic;
  h.version = kInstancedVersion;
  h.bits = static_cast<std::uint8_t>(grid.bits);
  for (std::size_t a = 0; a < 3; ++a) {
    h.origin[a] = grid.origin[a];
    h.high[a] = grid.high[a];
  }
  h.step = grid.step;
  return h;
}

// A section without pools: every point plain (a unit whose pools would not pay).
std::vector<std::byte> plainSection(std::span<const Splat> points, const QuantizedCell& grid,
                                    InstancingStats& stats) {
  InstancedHeader h = sectionHeader(grid);
  h.remainderOffset = sizeof(InstancedHeader);
  h.remainderCount = static_cast<std::uint32_t>(points.size());
  h.sectionBytes = static_cast<std::uint32_t>(h.remainderOffset + points.size_bytes());
  std::vector<std::byte> out(h.sectionBytes);
  std::memcpy(out.data(), &h, sizeof h);
  std::memcpy(out.data() + sizeof h, points.data(), points.size_bytes());
  stats.sectionBytes += out.size();
  return out;
}

}  // namespace

std::vector<std::byte> encodeInstancedCell(std::span<const Splat> points, const QuantizedCell& grid,
                                           std::span<const TranslationCount> palette,
                                           const InstancingOptions& options,
                                           InstancingStats& stats) {
  stats.cells += 1;
  stats.points += points.size();
  stats.plainBytes += points.size() * sizeof(Splat);
  if (palette.size() > kWords * 64)
    throw Error("internal error: a palette of " + std::to_string(palette.size()) +
                " translations, at most 256");
  if (points.empty()) return {};
  if (palette.empty()) return plainSection(points, grid, stats);

  // Distinct voxels; the first point of a voxel stands for it, the others stay plain.
  thread_local Occupancy occupancy;
  occupancy.reset(grid.dims);
  std::vector<std::uint32_t> rep;  // distinct voxel -> point
  for (std::uint32_t i = 0; i < points.size(); ++i) {
    std::int32_t& slot = occupancy.slot(grid.voxels[i]);
    if (slot < 0) {
      slot = static_cast<std::int32_t>(rep.size());
      rep.push_back(i);
    }
  }
  const std::size_t n = rep.size();
  auto voxelOf = [&](std::size_t u) -> const Voxel& { return grid.voxels[rep[u]]; };
  auto target = [&](std::size_t u, const std::array<std::int32_t, 3>& t) {
    const Voxel& v = voxelOf(u);
    return occupancy.at(v.q[0] + t[0], v.q[1] + t[1], v.q[2] + t[2]);
  };

  const double cosNormal = std::cos(options.normalToleranceDegrees * std::numbers::pi / 180.0);
  auto mayStandFor = [&](const Splat& source, const Splat& other) {
    if (colorDifference(source, other) > options.colorTolerance) return false;
    const bool a = knownNormal(source), b = knownNormal(other);
    if (a != b) return false;
    if (a) {
      auto dot = [](const float* x, const float* y) {
        return double{x[0]} * double{y[0]} + double{x[1]} * double{y[1]} +
               double{x[2]} * double{y[2]};
      };
      const double lengths =
          std::sqrt(dot(source.normal, source.normal) * dot(other.normal, other.normal));
      if (dot(source.normal, other.normal) < cosNormal * lengths) return false;
    }
    return std::abs(double{source.radius} - double{other.radius}) <=
           options.radiusTolerance * std::max(double{source.radius}, double{other.radius});
  };

  // Column j, bit i: translation i takes voxel j to a point j may stand for.
  std::vector<Column> column(n, Column{});
  for (std::size_t u = 0; u < n; ++u)
    for (std::size_t i = 0; i < palette.size(); ++i) {
      const std::int32_t k = target(u, palette[i].t);
      if (k >= 0 && mayStandFor(points[rep[u]], points[rep[std::size_t(k)]]))
        column[u][i / 64] |= std::uint64_t{1} << (i % 64);
    }

  struct BuiltPool {
    std::vector<std::uint32_t> rows;  // palette indices, after the null translation
    std::vector<InstancedVertex> vertices;
    std::uint64_t generated = 0;
  };
  std::vector<BuiltPool> pools;
  std::vector<std::uint8_t> covered(n, 0);
  std::vector<std::uint32_t> sourceOf(n, 0);  // distinct voxel -> the voxel generating it
  std::vector<std::uint32_t> order;
  std::vector<int> rowSum(palette.size());
  float maxRadius = 0.0f;
  for (const Splat& p : points) maxRadius = std::max(maxRadius, p.radius);
  const float radiusUnit = maxRadius / 65535.0f;

  while (pools.size() < options.maxPools) {
    // §4.1: the vertex with the most ones in its column, and its rows.
    std::size_t best = 0;
    int bestOnes = 0;
    for (std::size_t u = 0; u < n; ++u)
      if (const int ones = popcount(column[u]); ones > bestOnes) {
        bestOnes = ones;
        best = u;
      }
    if (bestOnes == 0) break;
    BuiltPool pool;
    for (std::uint32_t i = 0; i < palette.size(); ++i)
      if ((column[best][i / 64] >> (i % 64)) & 1u) pool.rows.push_back(i);
    const std::size_t rowLimit =
        std::clamp<std::size_t>(options.poolTranslations, 2, kPoolTranslations) - 1;
    if (pool.rows.size() > rowLimit) {
      // More than a tag holds: keep the rows with most ones overall.
      std::fill(rowSum.begin(), rowSum.end(), 0);
      for (std::size_t u = 0; u < n; ++u)
        for (const std::uint32_t i : pool.rows)
          rowSum[i] += int((column[u][i / 64] >> (i % 64)) & 1u);
      std::stable_sort(pool.rows.begin(), pool.rows.end(),
                       [&](std::uint32_t a, std::uint32_t b) { return rowSum[a] > rowSum[b]; });
      pool.rows.resize(rowLimit);
      std::sort(pool.rows.begin(), pool.rows.end());
    }
    Column mask{};
    for (const std::uint32_t i : pool.rows) mask[i / 64] |= std::uint64_t{1} << (i % 64);
    std::vector<int> score(n, 0);
    order.clear();
    for (std::uint32_t u = 0; u < n; ++u) {
      for (std::size_t w = 0; w < kWords; ++w) score[u] += std::popcount(column[u][w] & mask[w]);
      if (score[u] > 0) order.push_back(u);
    }
    std::stable_sort(order.begin(), order.end(),
                     [&](std::uint32_t a, std::uint32_t b) { return score[a] > score[b]; });
    const double threshold = options.acceptShare * static_cast<double>(pool.rows.size());
    std::vector<std::uint32_t> newlyCovered;
    std::vector<std::pair<std::uint32_t, std::uint32_t>> reach;  // (row slot, target)
    for (const std::uint32_t u : order) {
      reach.clear();
      for (std::uint32_t r = 0; r < pool.rows.size(); ++r) {
        const std::uint32_t i = pool.rows[r];
        if (!((column[u][i / 64] >> (i % 64)) & 1u)) continue;
        const std::int32_t k = target(u, palette[i].t);
        if (k >= 0 && !covered[std::size_t(k)]) reach.emplace_back(r + 1, std::uint32_t(k));
      }
      if (static_cast<double>(reach.size()) <= threshold) continue;
      const Splat& s = points[rep[u]];
      InstancedVertex v{};
      for (std::size_t a = 0; a < 3; ++a) v.q[a] = static_cast<std::uint16_t>(voxelOf(u).q[a]);
      v.radius = radiusUnit > 0.0f
                     ? static_cast<std::uint16_t>(
                           std::min(65535.0f, std::max(1.0f, std::ceil(s.radius / radiusUnit))))
                     : 0;
      std::memcpy(v.color, s.color, 4);
      for (int a = 0; a < 3; ++a)
        v.normal[a] =
            static_cast<std::int8_t>(std::lround(std::clamp(s.normal[a], -1.0f, 1.0f) * 127.0f));
      if (!covered[u]) {  // the vertex's own point, through the null translation
        tagSet(v, 0);
        covered[u] = 1;
        sourceOf[u] = u;
        newlyCovered.push_back(u);
      }
      for (const auto& [slot, k] : reach) {
        tagSet(v, slot);
        covered[k] = 1;
        sourceOf[k] = u;
        newlyCovered.push_back(k);
      }
      pool.vertices.push_back(v);
    }
    pool.generated = newlyCovered.size();
    if (pool.generated < options.minPoolPoints) {
      for (const std::uint32_t k : newlyCovered) covered[k] = 0;
      break;
    }
    // §4.2: whatever could have generated a covered point no longer counts it.
    for (const std::uint32_t k : newlyCovered) {
      const Voxel& v = voxelOf(k);
      for (std::size_t i = 0; i < palette.size(); ++i) {
        const auto& t = palette[i].t;
        const std::int32_t j = occupancy.at(v.q[0] - t[0], v.q[1] - t[1], v.q[2] - t[2]);
        if (j >= 0) column[std::size_t(j)][i / 64] &= ~(std::uint64_t{1} << (i % 64));
      }
    }
    pools.push_back(std::move(pool));
  }
  if (pools.empty()) return plainSection(points, grid, stats);

  // Encode: header, pool table, translations and vertices per pool, remainder.
  std::vector<std::byte> out;
  InstancedHeader h = sectionHeader(grid);
  h.poolCount = static_cast<std::uint8_t>(pools.size());
  h.radiusUnit = radiusUnit;
  std::size_t offset = sizeof(InstancedHeader) + pools.size() * sizeof(InstancedPool);
  std::vector<InstancedPool> table;
  for (const BuiltPool& p : pools) {
    InstancedPool entry{};
    entry.translationCount = static_cast<std::uint32_t>(p.rows.size() + 1);
    entry.vertexCount = static_cast<std::uint32_t>(p.vertices.size());
    entry.translationOffset = static_cast<std::uint32_t>(offset);
    offset += entry.translationCount * sizeof(InstancedTranslation);
    entry.vertexOffset = static_cast<std::uint32_t>(offset);
    offset += entry.vertexCount * sizeof(InstancedVertex);
    table.push_back(entry);
    h.generatedCount += static_cast<std::uint32_t>(p.generated);
  }
  std::vector<std::uint32_t> remainder;
  for (std::uint32_t i = 0; i < points.size(); ++i) {
    const std::int32_t u = occupancy.slot(grid.voxels[i]);
    if (rep[std::size_t(u)] != i || !covered[std::size_t(u)]) remainder.push_back(i);
  }
  h.remainderOffset =
      static_cast<std::uint32_t>((offset + sizeof(Splat) - 1) / sizeof(Splat) * sizeof(Splat));
  h.remainderCount = static_cast<std::uint32_t>(remainder.size());
  h.sectionBytes = static_cast<std::uint32_t>(h.remainderOffset + remainder.size() * sizeof(Splat));
  const std::size_t padded = (h.sectionBytes + sizeof(Splat) - 1) / sizeof(Splat) * sizeof(Splat);
  if (static_cast<double>(padded) > options.keepShare * double(points.size() * sizeof(Splat)))
    return plainSection(points, grid, stats);

  out.reserve(padded);
  appendBytes(out, h);
  for (const InstancedPool& entry : table) appendBytes(out, entry);
  for (const BuiltPool& p : pools) {
    appendBytes(out, InstancedTranslation{});
    for (const std::uint32_t i : p.rows) {
      InstancedTranslation t{};
      for (std::size_t a = 0; a < 3; ++a) t.t[a] = static_cast<std::int16_t>(palette[i].t[a]);
      appendBytes(out, t);
    }
    for (const InstancedVertex& v : p.vertices) appendBytes(out, v);
  }
  padTo(out, sizeof(Splat));
  for (const std::uint32_t i : remainder) appendBytes(out, points[i]);
  padTo(out, sizeof(Splat));

  stats.cellsInstanced += 1;
  stats.covered += h.generatedCount;
  stats.pools += pools.size();
  for (const BuiltPool& p : pools) {
    stats.vertices += p.vertices.size();
    stats.translations += p.rows.size() + 1;
    stats.vertexBytes += p.vertices.size() * (sizeof(InstancedVertex) - sizeof(std::uint32_t) * 2);
    stats.tagBytes += p.vertices.size() * sizeof(std::uint32_t) * 2;
    stats.translationBytes += (p.rows.size() + 1) * sizeof(InstancedTranslation);
  }
  stats.sectionBytes += out.size();
  for (std::size_t k = 0; k < n; ++k) {
    if (!covered[k]) continue;
    const Splat& original = points[rep[k]];
    const int error = colorDifference(points[rep[sourceOf[k]]], original);
    stats.colorErrorSum += error;
    stats.colorErrorMax = std::max(stats.colorErrorMax, error);
    float decoded[3];
    instancedPosition(h, voxelOf(k).q, decoded);
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) {
      const double d = double{decoded[a]} - double{original.position[a]};
      d2 += d * d;
    }
    stats.positionErrorMax = std::max(stats.positionErrorMax, std::sqrt(d2));
  }
  return out;
}

std::vector<std::byte> instanceCell(std::span<const Splat> points, const InstancingOptions& options,
                                    InstancingStats& stats) {
  const QuantizedCell grid = quantizeCell(points, options);
  // Too few points to repeat: no palette, a plain section.
  if (points.size() < options.minCellPoints)
    return encodeInstancedCell(points, grid, {}, options, stats);
  // The palette counts distinct voxels: a second point in a voxel is no translation.
  std::vector<Voxel> distinct(grid.voxels);
  std::sort(distinct.begin(), distinct.end());
  distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
  const double before = fftSecondsThisThread();
  const auto palette =
      translationPalette(distinct, grid.dims, options.paletteSize, options.paletteWindow);
  stats.fftSeconds += fftSecondsThisThread() - before;
  return encodeInstancedCell(points, grid, palette, options, stats);
}

std::vector<std::uint32_t> instancingUnits(std::span<const OctreeCell> cells, std::uint32_t root,
                                           std::uint32_t unitPoints) {
  std::vector<std::uint32_t> units;
  const std::uint32_t end = cells[root].nextSibling == kNoIndex
                                ? static_cast<std::uint32_t>(cells.size())
                                : cells[root].nextSibling;
  for (std::uint32_t i = root; i < end;) {
    const OctreeCell& c = cells[i];
    if (c.pointsCount <= unitPoints || c.isLeaf()) {
      units.push_back(i);
      i = c.nextSibling == kNoIndex ? end : c.nextSibling;
    } else {
      ++i;
    }
  }
  return units;
}

InstancingStats addInstancedSections(
    DatasetContent& content, const InstancingOptions& options, unsigned threads,
    const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
  auto& table = content.topLevel;
  const std::size_t count = table.size();
  std::vector<std::uint64_t> begin(count + 1, 0);
  for (std::size_t k = 0; k < count; ++k) begin[k + 1] = begin[k] + table[k].pointCount;
  if (begin[count] != content.points.size())
    throw Error("internal error: instancing needs every point of the dataset in memory");
  struct UnitSection {
    std::uint32_t cell;
    std::uint32_t offset;  // records from the start of its top-level cell's sections
    std::uint32_t records;
  };
  struct TopSections {
    std::vector<std::byte> bytes;
    std::vector<UnitSection> units;
  };
  std::vector<TopSections> sections(count);
  InstancingStats total;
  std::mutex mutex;
  std::atomic<std::uint64_t> done{0};
  std::atomic<bool> stop{false};
  std::exception_ptr error;
  const auto caller = std::this_thread::get_id();
  if (progress) progress(0, begin[count]);
  parallelFor(
      count, threads,
      [&](std::size_t k) {
        if (stop) return;
        try {
          InstancingStats stats;
          const std::span<const Splat> packetPoints =
              std::span<const Splat>(content.points).subspan(begin[k], table[k].pointCount);
          const std::uint32_t base = content.cells[table[k].cellIndex].pointsOffset;
          TopSections& out = sections[k];
          for (const std::uint32_t unit :
               instancingUnits(content.cells, table[k].cellIndex, options.unitPoints)) {
            const OctreeCell& c = content.cells[unit];
            const auto bytes = instanceCell(
                packetPoints.subspan(c.pointsOffset - base, c.pointsCount), options, stats);
            if (bytes.empty()) continue;
            out.units.push_back({unit, static_cast<std::uint32_t>(out.bytes.size() / sizeof(Splat)),
                                 static_cast<std::uint32_t>(bytes.size() / sizeof(Splat))});
            out.bytes.insert(out.bytes.end(), bytes.begin(), bytes.end());
          }
          {
            std::lock_guard lock(mutex);
            total.merge(stats);
          }
          done += table[k].pointCount;
          if (progress && std::this_thread::get_id() == caller) progress(done, begin[count]);
        } catch (...) {
          std::lock_guard lock(mutex);
          if (!error) error = std::current_exception();
          stop = true;
        }
      },
      1);
  if (error) std::rethrow_exception(error);

  std::size_t all = 0;
  for (const TopSections& t : sections) all += t.bytes.size() / sizeof(Splat);
  content.instancedRecords.assign(all, Splat{});
  auto* out = reinterpret_cast<std::byte*>(content.instancedRecords.data());
  std::vector<InstancedCellSection> perCell(content.cells.size());
  for (std::size_t k = 0; k < count; ++k) {
    const auto records = static_cast<std::uint32_t>(sections[k].bytes.size() / sizeof(Splat));
    if (std::uint64_t{table[k].levelSplatCount} + records + table[k].pointCount >
        std::numeric_limits<std::uint32_t>::max())
      throw UsageError("top-level cell " + std::to_string(k) +
                       " with its instanced sections holds more than 32-bit offsets address; "
                       "use a deeper --top-level-depth");
    std::memcpy(out, sections[k].bytes.data(), sections[k].bytes.size());
    out += sections[k].bytes.size();
    table[k].instancedRecordCount = records;
    for (const UnitSection& u : sections[k].units)
      perCell[u.cell] = {table[k].levelSplatCount + u.offset, u.records};
  }
  for (OctreeCell& c : content.cells)
    if (c.topLevel != kNoIndex) c.pointsOffset += table[c.topLevel].instancedRecordCount;
  DatasetContent::ExtraFile file{
      std::string(kInstancedSectionsKey), std::string(kInstancedSectionsName), {}};
  file.bytes.resize(perCell.size() * sizeof(InstancedCellSection));
  if (!perCell.empty()) std::memcpy(file.bytes.data(), perCell.data(), file.bytes.size());
  std::erase_if(content.extraFiles, [](const auto& f) { return f.key == kInstancedSectionsKey; });
  content.extraFiles.push_back(std::move(file));
  if (progress) progress(begin[count], begin[count]);
  return total;
}

}  // namespace pointillist::preprocess
