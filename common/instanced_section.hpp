#pragma once
// A top-level cell's points as interacting vertex and transformation streams
// (seed 000): the instanced section of a packet, written by
// `pointillist-preprocess --instanced` and drawn by the `instanced` render mode.
//
// The section sits in the packet between the level-splats and the original
// points (common/octree_cell.hpp, TopLevelCell::instancedRecordCount), as
// 32-byte records that are not splats, so data-send processes, render caches
// and prefixes count it like any other part of the packet. Layout, all
// little-endian, offsets in bytes from the section's start:
//
//   InstancedHeader (64 B)
//   InstancedPool[poolCount] (16 B each)
//   per pool: InstancedTranslation[translationCount] (8 B), then
//             InstancedVertex[vertexCount] (24 B)
//   Splat[remainderCount] (32 B, at a multiple of 32): the points no pool covers
//   zero padding to a multiple of 32
//
// Positions are quantized on the cell's grid: voxel q decodes to
// clamp(origin + q * step, origin, high), inside the cell's points' bounds (so
// the cell's culling bounds still hold every generated point). Pool p generates, for every
// translation i (instance) and every vertex v whose tag has bit i set, the point at voxel v.q + t_i
// with v's radius, colour and normal (seed 000 §3: the tag bit masks; translation 0 is the null
// translation, so a vertex's own voxel is drawn through bit 0).
#include <cstddef>
#include <cstdint>
#include <span>
#include <type_traits>
#include <vector>

#include "common/splat.hpp"

namespace pointillist {

inline constexpr std::uint32_t kInstancedMagic = 0x53495450u;  // "PTIS"
inline constexpr std::uint16_t kInstancedVersion = 1;
// Translations a pool may hold (the null one included): one bit each in a tag.
inline constexpr std::uint32_t kPoolTranslations = 64;
inline constexpr std::uint32_t kMaxInstancedBits = 16;

struct InstancedHeader {
  std::uint32_t magic;
  std::uint16_t version;
  std::uint8_t bits;  // grid resolution: voxel coordinates are below 2^bits
  std::uint8_t poolCount;
  std::uint32_t remainderCount;
  std::uint32_t generatedCount;  // points the pools generate
  std::uint32_t remainderOffset;
  std::uint32_t sectionBytes;  // without the final padding
  float origin[3];
  float step;
  float radiusUnit;  // InstancedVertex::radius * radiusUnit is the world radius
  float high[3];     // the cell's points' largest coordinates: decoded voxels are clamped to it
  std::uint32_t reserved[2];
};

struct InstancedPool {
  std::uint32_t vertexCount;
  std::uint32_t translationCount;  // 1..kPoolTranslations, the first is (0,0,0)
  std::uint32_t translationOffset;
  std::uint32_t vertexOffset;
};

struct InstancedTranslation {
  std::int16_t t[3];
  std::int16_t pad;
};

struct InstancedVertex {
  std::uint16_t q[3];
  std::uint16_t radius;   // in radiusUnit, rounded up
  std::uint8_t color[4];  // RGBA8
  std::int8_t normal[4];  // snorm8 xyz, (0,0,0) when unknown; w unused
  std::uint32_t tag[2];   // bit i: translation i applies to this vertex
};

static_assert(sizeof(InstancedHeader) == 64);
static_assert(sizeof(InstancedPool) == 16);
static_assert(sizeof(InstancedTranslation) == 8);
static_assert(sizeof(InstancedVertex) == 24);
static_assert(std::is_trivially_copyable_v<InstancedVertex>);

inline bool tagHas(const InstancedVertex& v, std::uint32_t i) {
  return ((v.tag[i >> 5] >> (i & 31u)) & 1u) != 0;
}
inline void tagSet(InstancedVertex& v, std::uint32_t i) {
  v.tag[i >> 5] |= 1u << (i & 31u);
}

// The extra dataset file instanced-sections.bin: one entry per octree cell,
// in cell order. A cell with records > 0 is an instancing unit with a section:
// records [offset, offset + records) of its top-level cell's packet stand for
// all the points of its subtree. Sections of one packet lie back to back
// between its level-splats and its points.
struct InstancedCellSection {
  std::uint32_t offset = 0;
  std::uint32_t records = 0;
};
static_assert(sizeof(InstancedCellSection) == 8);
inline constexpr const char* kInstancedSectionsKey = "instanced_sections";
inline constexpr const char* kInstancedSectionsName = "instanced-sections.bin";

// A checked view of one section; spans point into the bytes given to parse.
struct InstancedSectionView {
  InstancedHeader header{};
  struct Pool {
    std::span<const InstancedTranslation> translations;
    std::span<const InstancedVertex> vertices;
  };
  std::vector<Pool> pools;
  std::span<const Splat> remainder;
};

// Checks magic, version, offsets, counts (tag bits only name existing
// translations, generatedCount equals the tags' bits) and that every
// generated voxel lies on the grid. Throws InputError naming `where`.
InstancedSectionView parseInstancedSection(std::span<const std::byte> bytes, const char* where);
// The same over a packet's records.
InstancedSectionView parseInstancedSection(std::span<const Splat> records, const char* where);

// The world position of voxel q + t: clamp(origin + (q + t) * step, origin,
// high), in float, as the instanced vertex shader computes it.
void instancedPosition(const InstancedHeader& h, const std::int32_t voxel[3], float out[3]);

// Every point the section stands for, as splats: the pools' generated points
// (pool by pool, translation by translation, vertex by vertex) then the
// remainder. What the GL path draws, for the CPU side (tests, statistics).
std::vector<Splat> expandInstancedSection(const InstancedSectionView& view);

// The pools' generated voxels (same order as expandInstancedSection).
struct Voxel {
  std::int32_t q[3];
  auto operator<=>(const Voxel&) const = default;
};
std::vector<Voxel> generatedVoxels(const InstancedSectionView& view);

}  // namespace pointillist
