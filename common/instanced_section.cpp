#include "common/instanced_section.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <string>

#include "common/errors.hpp"

namespace pointillist {

namespace {

template <typename T>
std::span<const T> arrayAt(std::span<const std::byte> bytes, std::uint64_t offset,
                           std::uint64_t count, const char* what, const std::string& at) {
  if (offset % alignof(T) != 0 || offset > bytes.size() ||
      count > (bytes.size() - offset) / sizeof(T))
    throw InputError(at + what + " (" + std::to_string(count) + " at byte " +
                     std::to_string(offset) + ") lies outside the section of " +
                     std::to_string(bytes.size()) + " bytes");
  return {reinterpret_cast<const T*>(bytes.data() + offset), static_cast<std::size_t>(count)};
}

}  // namespace

InstancedSectionView parseInstancedSection(std::span<const std::byte> bytes, const char* where) {
  const std::string at = std::string(where) + ": instanced section: ";
  InstancedSectionView view;
  if (bytes.size() < sizeof(InstancedHeader))
    throw InputError(at + "only " + std::to_string(bytes.size()) + " bytes, less than a header");
  if (reinterpret_cast<std::uintptr_t>(bytes.data()) % alignof(InstancedVertex) != 0)
    throw Error("internal error: instanced section bytes are not aligned");
  std::memcpy(&view.header, bytes.data(), sizeof(InstancedHeader));
  const InstancedHeader& h = view.header;
  if (h.magic != kInstancedMagic) throw InputError(at + "bad magic number");
  if (h.version != kInstancedVersion)
    throw InputError(at + "version " + std::to_string(h.version) + ", this build reads " +
                     std::to_string(kInstancedVersion));
  if (h.bits == 0 || h.bits > kMaxInstancedBits)
    throw InputError(at + "grid of " + std::to_string(h.bits) + " bits");
  if (!(std::isfinite(h.step) && h.step > 0.0f) || !std::isfinite(h.radiusUnit) ||
      h.radiusUnit < 0.0f || !std::isfinite(h.origin[0]) || !std::isfinite(h.origin[1]) ||
      !std::isfinite(h.origin[2]) || !(h.high[0] >= h.origin[0]) || !(h.high[1] >= h.origin[1]) ||
      !(h.high[2] >= h.origin[2]) || !std::isfinite(h.high[0]) || !std::isfinite(h.high[1]) ||
      !std::isfinite(h.high[2]))
    throw InputError(at + "origin, bounds, step or radius unit is not finite and positive");
  if (h.sectionBytes > bytes.size())
    throw InputError(at + "says " + std::to_string(h.sectionBytes) + " bytes, has " +
                     std::to_string(bytes.size()));
  const auto pools =
      arrayAt<InstancedPool>(bytes, sizeof(InstancedHeader), h.poolCount, "the pool table", at);
  const std::int64_t gridEnd = std::int64_t{1} << h.bits;
  std::uint64_t generated = 0;
  for (std::size_t p = 0; p < pools.size(); ++p) {
    const InstancedPool& pool = pools[p];
    const std::string poolAt = at + "pool " + std::to_string(p) + ": ";
    if (pool.translationCount == 0 || pool.translationCount > kPoolTranslations)
      throw InputError(poolAt + std::to_string(pool.translationCount) + " translations (1.." +
                       std::to_string(kPoolTranslations) + ")");
    InstancedSectionView::Pool out;
    out.translations = arrayAt<InstancedTranslation>(bytes, pool.translationOffset,
                                                     pool.translationCount, "translations", poolAt);
    out.vertices =
        arrayAt<InstancedVertex>(bytes, pool.vertexOffset, pool.vertexCount, "vertices", poolAt);
    const InstancedTranslation& null = out.translations[0];
    if (null.t[0] != 0 || null.t[1] != 0 || null.t[2] != 0)
      throw InputError(poolAt + "translation 0 is not the null translation");
    const std::uint64_t unused = pool.translationCount == kPoolTranslations
                                     ? 0
                                     : ~((std::uint64_t{1} << pool.translationCount) - 1);
    for (const InstancedVertex& v : out.vertices) {
      const std::uint64_t tag = std::uint64_t{v.tag[0]} | (std::uint64_t{v.tag[1]} << 32);
      if ((tag & unused) != 0) throw InputError(poolAt + "a tag names a missing translation");
      generated += static_cast<std::uint64_t>(std::popcount(tag));
      for (std::uint32_t i = 0; i < pool.translationCount; ++i) {
        if (!tagHas(v, i)) continue;
        for (int a = 0; a < 3; ++a) {
          const std::int64_t c = std::int64_t{v.q[a]} + out.translations[i].t[a];
          if (c < 0 || c >= gridEnd)
            throw InputError(poolAt + "a generated voxel lies off the " + std::to_string(h.bits) +
                             "-bit grid");
        }
      }
    }
    view.pools.push_back(out);
  }
  if (generated != h.generatedCount)
    throw InputError(at + "tags generate " + std::to_string(generated) + " points, header says " +
                     std::to_string(h.generatedCount));
  if (h.remainderOffset % sizeof(Splat) != 0)
    throw InputError(at + "remainder offset " + std::to_string(h.remainderOffset) +
                     " is not a multiple of 32");
  view.remainder = arrayAt<Splat>(bytes, h.remainderOffset, h.remainderCount, "remainder", at);
  return view;
}

InstancedSectionView parseInstancedSection(std::span<const Splat> records, const char* where) {
  return parseInstancedSection(std::as_bytes(records), where);
}

void instancedPosition(const InstancedHeader& h, const std::int32_t voxel[3], float out[3]) {
  for (int a = 0; a < 3; ++a)
    out[a] =
        std::clamp(h.origin[a] + static_cast<float>(voxel[a]) * h.step, h.origin[a], h.high[a]);
}

namespace {

// Calls fn(vertex, voxel) for every generated point, pool by pool,
// translation by translation, vertex by vertex.
template <typename Fn>
void forEachGenerated(const InstancedSectionView& view, Fn fn) {
  for (const auto& pool : view.pools)
    for (std::uint32_t i = 0; i < pool.translations.size(); ++i)
      for (const InstancedVertex& v : pool.vertices)
        if (tagHas(v, i)) {
          const InstancedTranslation& t = pool.translations[i];
          fn(v, Voxel{{v.q[0] + t.t[0], v.q[1] + t.t[1], v.q[2] + t.t[2]}});
        }
}

}  // namespace

std::vector<Splat> expandInstancedSection(const InstancedSectionView& view) {
  std::vector<Splat> out;
  out.reserve(view.header.generatedCount + view.remainder.size());
  forEachGenerated(view, [&](const InstancedVertex& v, const Voxel& voxel) {
    Splat s{};
    instancedPosition(view.header, voxel.q, s.position);
    float len2 = 0.0f;
    for (int a = 0; a < 3; ++a) {
      s.normal[a] = static_cast<float>(v.normal[a]) / 127.0f;
      len2 += s.normal[a] * s.normal[a];
    }
    if (len2 > 0.0f)
      for (float& c : s.normal) c /= std::sqrt(len2);
    s.radius = static_cast<float>(v.radius) * view.header.radiusUnit;
    std::memcpy(s.color, v.color, 4);
    out.push_back(s);
  });
  out.insert(out.end(), view.remainder.begin(), view.remainder.end());
  return out;
}

std::vector<Voxel> generatedVoxels(const InstancedSectionView& view) {
  std::vector<Voxel> out;
  out.reserve(view.header.generatedCount);
  forEachGenerated(view, [&](const InstancedVertex&, const Voxel& voxel) { out.push_back(voxel); });
  return out;
}

}  // namespace pointillist
