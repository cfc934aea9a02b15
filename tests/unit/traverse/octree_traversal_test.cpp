// The traverse walk against brute force: the sibling-skip loop visits what a
// recursive walk visits, tiles never lose a splat that touches them, and tiles
// draw only what the full frame draws.
#include <gtest/gtest.h>

#include <functional>
#include <map>
#include <random>
#include <set>

#include "common/camera.hpp"
#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"
#include "traverse/core/octree_traversal.hpp"

namespace pointillist::traverse {
namespace {

struct Fixture {
  DatasetContent content;
  glm::vec3 boundsMin, boundsMax;
};

const Fixture& cityFixture() {
  static const Fixture fixture = [] {
    Fixture f;
    auto cloud = preprocess::generateScene("city", 30'000, 7);
    preprocess::PreprocessOptions options;
    options.octree.leafPoints = 64;
    options.topLevelDepth = 2;
    f.content = preprocess::buildDatasetContent(std::move(cloud.splats), options);
    finalizeDatasetContent(f.content);
    const auto& m = f.content.manifest;
    f.boundsMin = {m.boundsMin[0], m.boundsMin[1], m.boundsMin[2]};
    f.boundsMax = {m.boundsMax[0], m.boundsMax[1], m.boundsMax[2]};
    return f;
  }();
  return fixture;
}

// Recursive reference of the same decisions, without the sibling-skip array trick.
void recursiveWalk(std::span<const OctreeCell> cells, std::uint32_t index, const Camera& camera,
                   const FrustumPlanes& planes, const TraversalSettings& settings,
                   std::vector<PacketRange>& out) {
  const OctreeCell& cell = cells[index];
  const float r = cell.maxSplatRadius * settings.sizeScale;
  const glm::vec3 low(cell.boundsMin[0] - r, cell.boundsMin[1] - r, cell.boundsMin[2] - r);
  const glm::vec3 high(cell.boundsMax[0] + r, cell.boundsMax[1] + r, cell.boundsMax[2] + r);
  if (boxOutside(planes, low, high)) return;
  if (settings.backfaceCull && cellBackfacing(cell, cameraEye(camera), settings.sizeScale)) return;
  bool descend = cell.topLevel == kNoIndex;
  if (!descend) {
    const float distance = distanceToCell(cell, cameraEye(camera), settings.sizeScale);
    const bool coarse = distance > 0.0f &&
                        projectedRadiusPixels(camera, r, distance) <= settings.lodPixels &&
                        cell.splatsCount > 0;
    if (coarse) {
      out.push_back({cell.topLevel, cell.splatsOffset, cell.splatsCount});
      return;
    }
    if (cell.isLeaf()) {
      if (cell.pointsCount > 0) out.push_back({cell.topLevel, cell.pointsOffset, cell.pointsCount});
      return;
    }
    descend = true;
  }
  if (cell.isLeaf()) return;
  // Children: index + 1, then each child's nextSibling until it leaves this subtree.
  std::uint32_t child = index + 1;
  const std::uint32_t end =
      cell.nextSibling == kNoIndex ? static_cast<std::uint32_t>(cells.size()) : cell.nextSibling;
  while (child < end) {
    recursiveWalk(cells, child, camera, planes, settings, out);
    child = cells[child].nextSibling == kNoIndex ? end : cells[child].nextSibling;
  }
}

std::set<std::pair<std::uint32_t, std::uint32_t>> splatSet(const std::vector<PacketRange>& ranges) {
  std::set<std::pair<std::uint32_t, std::uint32_t>> set;
  for (const auto& range : ranges) {
    for (std::uint32_t i = 0; i < range.count; ++i) set.insert({range.topLevel, range.offset + i});
  }
  return set;
}

const Splat& splatAt(const DatasetContent& content, std::uint32_t topLevel, std::uint32_t offset) {
  const TopLevelCell& entry = content.topLevel[topLevel];
  // Packet k = its level-splats (layered, in table order) then its points.
  std::uint64_t pointsBefore = 0, splatsBefore = 0;
  for (std::uint32_t k = 0; k < topLevel; ++k) {
    pointsBefore += content.topLevel[k].pointCount;
    splatsBefore += content.topLevel[k].levelSplatCount;
  }
  if (offset < entry.levelSplatCount) return content.levelSplats[splatsBefore + offset];
  return content.points[pointsBefore + offset - entry.levelSplatCount];
}

std::vector<Camera> testCameras(const Fixture& f) {
  std::vector<Camera> cameras;
  cameras.push_back(cameraForBounds(f.boundsMin, f.boundsMax, 320, 200, 30.0f, 25.0f, 1.0f));
  cameras.push_back(cameraForBounds(f.boundsMin, f.boundsMax, 320, 200, 200.0f, 10.0f, 0.35f));
  cameras.push_back(cameraForBounds(f.boundsMin, f.boundsMax, 256, 256, 95.0f, 60.0f, 3.0f));
  return cameras;
}

TEST(OctreeTraversal, SiblingSkipMatchesRecursiveWalk) {
  const Fixture& f = cityFixture();
  for (const Camera& camera : testCameras(f)) {
    for (bool cull : {true, false}) {
      TraversalSettings settings;
      settings.backfaceCull = cull;
      for (const TileRect& rect :
           {fullFrameRect(camera), makeTileRect(0, 0, 100, 80), makeTileRect(150, 90, 64, 64)}) {
        const auto result = traverseTile(f.content.cells, camera, rect, settings);
        std::vector<PacketRange> expected;
        recursiveWalk(f.content.cells, 0, camera, tilePlanes(camera, rect, settings.marginPixels),
                      settings, expected);
        EXPECT_EQ(splatSet(result.ranges), splatSet(expected));
        std::uint64_t count = 0;
        for (const auto& range : expected) count += range.count;
        EXPECT_EQ(result.splats, count);
      }
    }
  }
}

// Skipping the planes a parent lies wholly inside, the facing test below a
// cell whose splats all face the eye, and the visit of children that would all
// be drawn from their level-splats, decides exactly as testing every cell:
// the same ranges, needs and counts, on whole frames and small tiles.
TEST(OctreeTraversal, InheritedCullingDecidesAsTestingEveryCell) {
  const Fixture& f = cityFixture();
  const CullingTable table(f.content.cells, 1.0f);
  std::size_t within = 0;
  for (std::uint32_t i = 1; i < f.content.cells.size(); ++i) within += table.withinParent(i);
  EXPECT_GT(within, f.content.cells.size() * 9 / 10);  // octree cells nest
  std::vector<Camera> cameras = testCameras(f);
  cameras.push_back(cameraForBounds(f.boundsMin, f.boundsMax, 320, 200, 10.0f, 20.0f, 0.2f));
  std::mt19937 rng(3);
  const auto below = [&rng](std::uint32_t n) { return static_cast<std::uint32_t>(rng() % n); };
  std::size_t toward = 0;
  std::uint64_t skipped = 0;
  for (const Camera& camera : cameras) {
    const glm::vec3 eye = cameraEye(camera);
    for (std::uint32_t i = 0; i < f.content.cells.size(); ++i) {
      toward += cellFacing(table[i], eye) == Facing::Toward;
    }
    for (int t = 0; t < 12; ++t) {
      const std::uint32_t w = 8 + below(200), h = 8 + below(150);
      const TileRect rect = t == 0 ? fullFrameRect(camera)
                                   : makeTileRect(below(camera.image_width() - w),
                                                  below(camera.image_height() - h), w, h);
      TraversalSettings settings;
      settings.backfaceCull = t % 4 != 3;
      const TraversalResult inherited = traverseTile(table, camera, rect, settings);
      settings.inheritCulling = false;
      const TraversalResult tested = traverseTile(table, camera, rect, settings);
      EXPECT_EQ(inherited.ranges, tested.ranges);
      EXPECT_EQ(inherited.needs, tested.needs);
      EXPECT_EQ(inherited.splats, tested.splats);
      // Children all drawn from their level-splats are taken at once, unvisited.
      EXPECT_LE(inherited.cellsVisited, tested.cellsVisited);
      skipped += tested.cellsVisited - inherited.cellsVisited;
      EXPECT_EQ(inherited.cellsCulledFrustum, tested.cellsCulledFrustum);
      EXPECT_EQ(inherited.cellsCulledBackface, tested.cellsCulledBackface);
    }
  }
  EXPECT_GT(toward, 0u);   // the facing shortcut is exercised
  EXPECT_GT(skipped, 0u);  // and so is the children's
}

TEST(OctreeTraversal, TilesDrawOnlyWhatTheFullFrameDrawsAndLoseNothingThatTouchesThem) {
  const Fixture& f = cityFixture();
  std::mt19937 random(3);
  std::size_t tilesWithSplats = 0;
  std::size_t tilesCulled = 0;
  for (const Camera& camera : testCameras(f)) {
    TraversalSettings settings;
    const auto full = traverseTile(f.content.cells, camera, fullFrameRect(camera), settings);
    ASSERT_GT(full.splats, 0u);
    const auto fullSet = splatSet(full.ranges);
    for (int trial = 0; trial < 6; ++trial) {
      const std::uint32_t w = 16 + static_cast<std::uint32_t>(random()) % 120,
                          h = 16 + static_cast<std::uint32_t>(random()) % 90;
      const std::uint32_t x = static_cast<std::uint32_t>(random()) % (camera.image_width() - w);
      const std::uint32_t y = static_cast<std::uint32_t>(random()) % (camera.image_height() - h);
      const TileRect rect = makeTileRect(x, y, w, h);
      const auto tile = traverseTile(f.content.cells, camera, rect, settings);
      const auto tileSet = splatSet(tile.ranges);
      for (const auto& key : tileSet) ASSERT_TRUE(fullSet.contains(key));
      // Every full-frame splat whose footprint reaches the tile must be in it.
      std::size_t touching = 0;
      for (const auto& [topLevel, offset] : fullSet) {
        const Splat& s = splatAt(f.content, topLevel, offset);
        const glm::vec3 p(s.position[0], s.position[1], s.position[2]);
        const glm::vec4 window = projectToWindow(camera, p);
        if (window.w <= 0.0f) continue;
        const float reach = projectedRadiusPixels(camera, s.radius, window.w) + 0.5f;
        const bool touches = window.x + reach >= static_cast<float>(x) &&
                             window.x - reach <= static_cast<float>(x + w) &&
                             window.y + reach >= static_cast<float>(y) &&
                             window.y - reach <= static_cast<float>(y + h);
        if (!touches) continue;
        ++touching;
        ASSERT_TRUE(tileSet.contains({topLevel, offset}))
            << "splat at pixel " << window.x << "," << window.y << " missing from tile " << x << ","
            << y << " " << w << "x" << h;
      }
      tilesWithSplats += touching > 0;
      tilesCulled += tileSet.size() < fullSet.size();
    }
  }
  // Not vacuous: tiles met splats, and the tile cull left some out.
  EXPECT_GT(tilesWithSplats, 0u);
  EXPECT_GT(tilesCulled, 0u);
}

// A split tile's part sends the box of its needs: every splat a need draws
// lies in that need's box with its whole footprint, and the walk's ranges
// are those of a walk without boxes.
TEST(OctreeTraversal, NeedBoxesHoldEverySplatTheirCellDraws) {
  const Fixture& f = cityFixture();
  std::size_t needs = 0, smallBoxes = 0;
  for (const Camera& camera : testCameras(f)) {
    TraversalSettings settings;
    const TileRect rect = makeTileRect(40, 30, 150, 120);
    const auto plain = traverseTile(f.content.cells, camera, rect, settings);
    EXPECT_TRUE(plain.needBoxes.empty());
    settings.screenBoxes = true;
    const auto walk = traverseTile(f.content.cells, camera, rect, settings);
    EXPECT_EQ(walk.ranges, plain.ranges);
    ASSERT_EQ(walk.needBoxes.size(), walk.needs.size());
    for (std::size_t i = 0; i < walk.needs.size(); ++i) {
      const ScreenBox& box = walk.needBoxes[i];
      ASSERT_FALSE(box.empty());
      ++needs;
      const TileRect clipped = clipScreenBox(box, rect);
      smallBoxes += std::uint64_t{clipped.width()} * clipped.height() <
                    std::uint64_t{rect.width()} * rect.height() / 2;
      for (const PacketRange& range : walk.ranges) {
        if (range.topLevel != walk.needs[i].cell) continue;
        for (std::uint32_t k = 0; k < range.count; ++k) {
          const Splat& s = splatAt(f.content, range.topLevel, range.offset + k);
          const glm::vec4 window =
              projectToWindow(camera, glm::vec3(s.position[0], s.position[1], s.position[2]));
          ASSERT_GT(window.w, 0.0f);
          const float reach = projectedRadiusPixels(camera, s.radius, window.w) + 0.5f;
          ASSERT_GE(window.x - reach, box.x0) << "need " << i;
          ASSERT_LE(window.x + reach, box.x1) << "need " << i;
          ASSERT_GE(window.y - reach, box.y0) << "need " << i;
          ASSERT_LE(window.y + reach, box.y1) << "need " << i;
        }
      }
    }
  }
  EXPECT_GT(needs, 4u);
  EXPECT_GT(smallBoxes, 0u) << "no need covers less than half the tile: the boxes show nothing";

  // Clipping: whole pixels inside the rect, nothing for a box outside it.
  const TileRect rect = makeTileRect(10, 20, 30, 40);
  const TileRect inside = clipScreenBox({12.5f, 25.2f, 19.1f, 70.0f}, rect);
  EXPECT_EQ(inside.x(), 12u);
  EXPECT_EQ(inside.y(), 25u);
  EXPECT_EQ(inside.width(), 8u);
  EXPECT_EQ(inside.height(), 35u);
  EXPECT_EQ(clipScreenBox({50.0f, 25.0f, 60.0f, 30.0f}, rect).width(), 0u);
  EXPECT_EQ(clipScreenBox({}, rect).width(), 0u);
  const TileRect everything = clipScreenBox({-1e30f, -1e30f, 1e30f, 1e30f}, rect);
  EXPECT_EQ(everything.x(), 10u);
  EXPECT_EQ(everything.width(), 30u);
  EXPECT_EQ(everything.height(), 40u);
}

std::vector<std::uint32_t> cellsOf(std::span<const CellPrefix> prefixes) {
  std::vector<std::uint32_t> cells;
  for (const CellPrefix& prefix : prefixes) cells.push_back(prefix.cell);
  return cells;
}

TEST(OctreeTraversal, PrefetchCellsAreASupersetOfWhatTheTileDrawsWhoseNeedsEndAtItsRanges) {
  const Fixture& f = cityFixture();
  const PacketLayers layers(f.content.cells, f.content.topLevel);
  std::size_t smallerThanFrame = 0;
  std::size_t insideLayer = 0;  // needs that end inside a layer, not on its end
  for (const Camera& camera : testCameras(f)) {
    for (const TileRect& rect :
         {fullFrameRect(camera), makeTileRect(0, 0, 100, 80), makeTileRect(150, 90, 64, 64)}) {
      TraversalSettings settings;
      const auto drawn = traverseTile(f.content.cells, camera, rect, settings);
      const auto aheadPrefixes =
          topLevelCellsInTile(f.content.cells, layers, camera, rect, settings);
      const auto ahead = cellsOf(aheadPrefixes);
      ASSERT_TRUE(std::is_sorted(ahead.begin(), ahead.end()));
      ASSERT_EQ(std::adjacent_find(ahead.begin(), ahead.end()), ahead.end());
      const auto drawnCells = cellsOf(drawn.needs);
      for (std::uint32_t cell : drawnCells) {
        EXPECT_TRUE(std::binary_search(ahead.begin(), ahead.end(), cell)) << "cell " << cell;
      }
      ASSERT_TRUE(std::is_sorted(drawnCells.begin(), drawnCells.end()));
      // A need's prefix ends at the end of the cell's last drawn range, not at
      // a layer's end.
      const auto onLayerEnd = [&](std::uint32_t cell, std::uint32_t splats) {
        const auto cellLayers = layers.layers(cell);
        return std::any_of(cellLayers.begin(), cellLayers.end(),
                           [&](const PacketLayer& layer) { return layer.end == splats; });
      };
      for (const CellPrefix& need : drawn.needs) {
        std::uint32_t lastEnd = 0;
        for (const PacketRange& range : drawn.ranges)
          if (range.topLevel == need.cell) lastEnd = std::max(lastEnd, range.offset + range.count);
        EXPECT_EQ(need.splats, lastEnd);
        insideLayer += !onLayerEnd(need.cell, need.splats);
      }
      // Estimated prefixes end on a layer and lie inside the packet.
      for (const CellPrefix& prefix : aheadPrefixes) {
        EXPECT_TRUE(onLayerEnd(prefix.cell, prefix.splats)) << "cell " << prefix.cell;
        EXPECT_GT(prefix.splats, 0u);
      }
      // Culled by the frustum: a tile names only cells the whole frame names.
      const auto whole = cellsOf(
          topLevelCellsInTile(f.content.cells, layers, camera, fullFrameRect(camera), settings));
      EXPECT_TRUE(std::includes(whole.begin(), whole.end(), ahead.begin(), ahead.end()));
      if (rect.width() < camera.image_width()) smallerThanFrame += ahead.size() < whole.size();
      for (std::uint32_t cell : whole) EXPECT_LT(cell, f.content.topLevel.size());
    }
  }
  EXPECT_GT(smallerThanFrame, 0u) << "no tile culled a top-level cell";
  EXPECT_GT(insideLayer, 0u) << "no need ended inside a layer";
}

TEST(OctreeTraversal, CoarserLevelOfDetailDrawsFewerSplats) {
  const Fixture& f = cityFixture();
  const Camera camera = testCameras(f)[2];  // far away
  TraversalSettings fine;
  fine.lodPixels = 0.25f;
  TraversalSettings coarse;
  coarse.lodPixels = 4.0f;
  const auto fineResult = traverseTile(f.content.cells, camera, fullFrameRect(camera), fine);
  const auto coarseResult = traverseTile(f.content.cells, camera, fullFrameRect(camera), coarse);
  EXPECT_LT(coarseResult.splats, fineResult.splats);
  EXPECT_GT(coarseResult.splats, 0u);
}

TEST(OctreeTraversal, RangesAreSortedMergedAndInsideTheirPackets) {
  const Fixture& f = cityFixture();
  for (const Camera& camera : testCameras(f)) {
    const auto result = traverseTile(f.content.cells, camera, fullFrameRect(camera), {});
    for (std::size_t i = 0; i < result.ranges.size(); ++i) {
      const auto& range = result.ranges[i];
      const auto& entry = f.content.topLevel.at(range.topLevel);
      EXPECT_LE(range.offset + range.count, entry.pointCount + entry.levelSplatCount);
      if (i > 0) {
        const auto& previous = result.ranges[i - 1];
        EXPECT_TRUE(previous.topLevel < range.topLevel ||
                    (previous.topLevel == range.topLevel &&
                     previous.offset + previous.count < range.offset));
      }
    }
    // One need per cell drawn from, ascending, reaching exactly the last range end.
    std::map<std::uint32_t, std::uint32_t> ends;
    for (const auto& range : result.ranges) {
      ends[range.topLevel] = std::max(ends[range.topLevel], range.offset + range.count);
    }
    ASSERT_EQ(result.needs.size(), ends.size());
    std::size_t i = 0;
    for (const auto& [cell, end] : ends) {
      EXPECT_EQ(result.needs[i].cell, cell);
      EXPECT_EQ(result.needs[i].splats, end);
      ++i;
    }
  }
}

TEST(OctreeTraversal, BackfacingCellIsCulledOnlyWhenEveryNormalFacesAway) {
  OctreeCell cell{};
  cell.boundsMin[0] = cell.boundsMin[1] = cell.boundsMin[2] = -1.0f;
  cell.boundsMax[0] = cell.boundsMax[1] = cell.boundsMax[2] = 1.0f;
  cell.maxSplatRadius = 0.1f;
  // All normals within ~10 degrees of +z.
  cell.coneAxis[0] = 0;
  cell.coneAxis[1] = 0;
  cell.coneAxis[2] = 32767;
  cell.coneCos = static_cast<std::int16_t>(0.98 * 32767);
  EXPECT_TRUE(cellBackfacing(cell, {0, 0, -20}, 1.0f));     // looking at the backs
  EXPECT_FALSE(cellBackfacing(cell, {0, 0, 20}, 1.0f));     // looking at the fronts
  EXPECT_FALSE(cellBackfacing(cell, {20, 0, 0.5f}, 1.0f));  // grazing: some may face us
  EXPECT_FALSE(cellBackfacing(cell, {0, 0, -0.5f}, 1.0f));  // eye inside the cell
  cell.coneCos = -32767;                                    // no cone
  EXPECT_FALSE(cellBackfacing(cell, {0, 0, -20}, 1.0f));
}

// The property back-face culling rests on, with the cone decoded once into the
// culling table: whenever a cell is culled, every splat the cell may hold (any
// position in its grown bounds, any normal in its cone) faces away from the eye.
TEST(OctreeTraversal, CulledCellsHoldOnlySplatsFacingAway) {
  std::mt19937 random(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::uniform_real_distribution<double> fraction(0.0, 1.0);
  const auto randomDirection = [&] {
    glm::dvec3 v;
    do v = {unit(random), unit(random), unit(random)};
    while (glm::length(v) < 0.1 || glm::length(v) > 1.0);
    return glm::normalize(v);
  };
  int culled = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    OctreeCell cell{};
    const double size = 0.2 + 2.0 * fraction(random);
    for (int k = 0; k < 3; ++k) {
      cell.boundsMin[k] = static_cast<float>(unit(random));
      cell.boundsMax[k] = cell.boundsMin[k] + static_cast<float>(size * (0.2 + fraction(random)));
    }
    cell.maxSplatRadius = static_cast<float>(0.05 * fraction(random));
    const glm::dvec3 axis = randomDirection();
    const double halfAngle = 0.6 * fraction(random);  // up to about 34 degrees
    encodeNormalCone(cell, quantizeConeAxis({axis.x, axis.y, axis.z}), std::cos(halfAngle));
    const glm::vec3 eye = glm::vec3(randomDirection() * (3.0 + 20.0 * fraction(random)));
    const float scale = trial % 2 == 0 ? 1.0f : 2.5f;
    const CellCulling culling = cellCulling(cell, scale);
    ASSERT_EQ(cellBackfacing(culling, eye), cellBackfacing(cell, eye, scale));
    if (!cellBackfacing(culling, eye)) continue;
    ++culled;
    const NormalCone cone = decodeNormalCone(cell);
    const glm::dvec3 coneAxis(cone.axis[0], cone.axis[1], cone.axis[2]);
    // Normals inside the stored cone, its rim included, and points inside the grown bounds.
    const glm::dvec3 u = glm::normalize(glm::cross(
        coneAxis, std::abs(coneAxis.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0)));
    const glm::dvec3 v = glm::cross(coneAxis, u);
    const double maxAngle = std::acos(std::clamp(cone.cosHalfAngle, -1.0, 1.0));
    for (int sample = 0; sample < 200; ++sample) {
      const double angle = sample % 4 == 0 ? maxAngle : maxAngle * std::sqrt(fraction(random));
      const double turn = 6.283185307179586 * fraction(random);
      const glm::dvec3 normal =
          std::cos(angle) * coneAxis + std::sin(angle) * (std::cos(turn) * u + std::sin(turn) * v);
      glm::dvec3 point;
      for (int k = 0; k < 3; ++k) {
        const double low = culling.low[k], high = culling.high[k];
        point[k] = low + (high - low) * fraction(random);
      }
      ASSERT_GT(glm::dot(normal, point - glm::dvec3(eye)), 0.0)
          << "trial " << trial << ": a splat of a culled cell faces the eye";
    }
  }
  EXPECT_GT(culled, 200);  // the property was exercised, not skipped
}

TEST(OctreeTraversal, CullingTableMustMatchTheWalksSizeScale) {
  const auto& f = cityFixture();
  const CullingTable table(f.content.cells, 1.0f);
  TraversalSettings settings;
  settings.sizeScale = 2.0f;
  const Camera camera = testCameras(f)[0];
  EXPECT_THROW(traverseTile(table, camera, fullFrameRect(camera), settings), UsageError);
  settings.sizeScale = 1.0f;
  EXPECT_EQ(traverseTile(table, camera, fullFrameRect(camera), settings).ranges,
            traverseTile(f.content.cells, camera, fullFrameRect(camera), settings).ranges);
}

// --mode instanced: a unit whose points the plain walk would draw (anywhere in
// the frame) draws its section instead, counted as the points it generates;
// units the walk leaves coarse stay coarse; tiles draw only sections and
// splats the full frame draws, and every section the full frame draws whose
// unit reaches into a tile is in that tile.
TEST(OctreeTraversal, InstancedModeDrawsSectionsWherePointsWereDrawn) {
  auto cloud = preprocess::generateScene("city", 30'000, 7);
  preprocess::PreprocessOptions options;
  options.octree.leafPoints = 64;
  options.topLevelDepth = 2;
  options.instancing = preprocess::InstancingOptions{};
  options.instancing->unitPoints = 256;
  DatasetContent content = preprocess::buildDatasetContent(std::move(cloud.splats), options);
  finalizeDatasetContent(content);
  ASSERT_EQ(content.extraFiles.size(), 1u);
  const auto instanced = std::make_shared<const InstancedCells>(
      content.cells, content.topLevel, content.extraFiles[0].bytes, "test");
  const auto& m = content.manifest;
  const glm::vec3 lo(m.boundsMin[0], m.boundsMin[1], m.boundsMin[2]);
  const glm::vec3 hi(m.boundsMax[0], m.boundsMax[1], m.boundsMax[2]);
  std::uint64_t sectionsSeen = 0;
  for (const Camera& camera : {cameraForBounds(lo, hi, 320, 200, 30.0f, 25.0f, 0.6f),
                               cameraForBounds(lo, hi, 320, 200, 200.0f, 10.0f, 0.35f)}) {
    TraversalSettings plain;
    TraversalSettings settings;
    settings.instanced = instanced;
    const auto points = traverseTile(content.cells, camera, fullFrameRect(camera), plain);
    const auto full = traverseTile(content.cells, camera, fullFrameRect(camera), settings);
    sectionsSeen += full.sections;
    // Points drawn by the plain walk lie in units drawn as sections; no point
    // range remains in instanced mode (every unit has a section).
    std::uint64_t expectedSplats = 0;
    for (const PacketRange& r : full.ranges) {
      const TopLevelCell& t = content.topLevel[r.topLevel];
      EXPECT_EQ(r.section, inInstancedSection(t, r.offset));
      EXPECT_LT(r.offset, pointsStart(t)) << "instanced mode drew plain points";
      if (!r.section) expectedSplats += r.count;
    }
    for (std::uint32_t i = 0; i < content.cells.size(); ++i) {
      const InstancedCells::Cell& unit = (*instanced)[i];
      if (unit.records == 0) continue;
      const OctreeCell& c = content.cells[i];
      const bool drawn = std::any_of(full.ranges.begin(), full.ranges.end(), [&](const auto& r) {
        return r.section && r.topLevel == c.topLevel && r.offset == unit.offset;
      });
      const bool hadPoints =
          std::any_of(points.ranges.begin(), points.ranges.end(), [&](const auto& r) {
            return r.topLevel == c.topLevel && r.offset >= c.pointsOffset &&
                   r.offset < c.pointsOffset + c.pointsCount;
          });
      if (hadPoints) {
        EXPECT_TRUE(drawn) << "unit " << i << " lost its points";
      }
      if (drawn) expectedSplats += c.pointsCount;
    }
    EXPECT_EQ(full.splats, expectedSplats);
    // Tiles: a subset of the full frame's ranges.
    const auto fullSet = splatSet(full.ranges);
    for (const TileRect& rect : {makeTileRect(0, 0, 160, 100), makeTileRect(160, 100, 160, 100)}) {
      const auto tile = traverseTile(content.cells, camera, rect, settings);
      for (const auto& key : splatSet(tile.ranges)) ASSERT_TRUE(fullSet.contains(key));
    }
  }
  EXPECT_GT(sectionsSeen, 0u);
}

}  // namespace
}  // namespace pointillist::traverse
