#include "simulator/scene.hpp"

#include <chrono>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/splat.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::simulator {

Scene::Scene(std::string name, std::vector<OctreeCell> cells, std::vector<TopLevelCell> topLevel,
             SceneBounds bounds, std::vector<Camera> cameras,
             const traverse::TraversalSettings& traversal, std::size_t loopFrames,
             std::unique_ptr<const LitPixels> litPixels, int compressionLevel)
    : name_(std::move(name)),
      cells_(std::move(cells)),
      topLevel_(std::move(topLevel)),
      layers_(std::make_shared<const traverse::PacketLayers>(cells_, topLevel_)),
      culling_(std::make_unique<const traverse::CullingTable>(cells_, traversal.sizeScale)),
      bounds_(bounds),
      cameras_(std::move(cameras)),
      loopFrames_(loopFrames),
      traversal_(traversal),
      litPixels_(std::move(litPixels)),
      compressionLevel_(litPixels_ != nullptr ? compressionLevel : 0) {
  if (cells_.empty() || topLevel_.empty()) {
    throw InputError(name_ + ": the dataset has no cells to simulate");
  }
  // Where each need draws: a part of a split tile sends only that box.
  traversal_.screenBoxes = traversal_.statistical == nullptr;
  if (cameras_.empty()) throw UsageError("the camera path has no frames to simulate");
}

Scene Scene::load(const std::string& datasetPath, const ViewOptions& view, bool litPixels,
                  unsigned threads, int compressionLevel) {
  if (datasetPath.empty()) throw UsageError("--dataset is required");
  const Dataset dataset =
      Dataset::open(datasetPath, litPixels ? DatasetParts::All : DatasetParts::Cells);
  const SceneBounds bounds = datasetBounds(dataset.manifest());
  const traverse::TraversalSettings traversal = traverse::traversalSettings(view);
  std::vector<Camera> cameras = viewCameras(view, bounds);
  const std::size_t loopFrames = view.loops > 1 ? cameras.size() / view.loops : 0;
  std::unique_ptr<const LitPixels> lit;
  // Statistical packets are drawn on GL only: their images keep the
  // splat-count model (the assumptions say which).
  if (litPixels && !dataset.hasStatistical()) {
    // One loop's frames: later loops see the same cameras.
    const std::size_t frames = loopFrames > 0 ? loopFrames : cameras.size();
    lit =
        std::make_unique<const LitPixels>(dataset, std::span<const Camera>(cameras.data(), frames),
                                          traversal, threads, compressionLevel);
  }
  const int measured = lit != nullptr ? compressionLevel : 0;
  return Scene(datasetPath, {dataset.cells().begin(), dataset.cells().end()},
               {dataset.topLevelCells().begin(), dataset.topLevelCells().end()}, bounds,
               std::move(cameras), traversal, loopFrames, std::move(lit), measured);
}

double Scene::imageCompression(std::uint64_t frame, bool part) const {
  if (!litPixels_ || compressionLevel_ == 0) return 1.0;
  if (loopFrames_ > 0) frame %= loopFrames_;
  const FrameCoverage& coverage = litPixels_->frame(frame, *culling_);
  return part ? coverage.partCompression() : coverage.wholeCompression();
}

LitRuns Scene::litRuns(std::uint64_t frame, const TileRect& box) const {
  if (!litPixels_) throw Error("internal error: the scene draws no lit pixels");
  if (loopFrames_ > 0) frame %= loopFrames_;
  return litPixels_->frame(frame, *culling_).count(box);
}

std::uint32_t Scene::width() const {
  return cameras_.front().image_width();
}

std::uint32_t Scene::height() const {
  return cameras_.front().image_height();
}

float Scene::marginWorld() const {
  return cells_.front().maxSplatRadius * traversal_.sizeScale;
}

std::uint64_t Scene::datasetBytes() const {
  std::uint64_t bytes = 0;
  for (const TopLevelCell& cell : topLevel_) bytes += cell.byteSize;
  return bytes;
}

std::size_t Scene::KeyHash::operator()(const Key& key) const {
  std::uint64_t h = key.frame * 0x9e3779b97f4a7c15ull;
  for (std::uint32_t value : {key.x, key.y, key.width, key.height}) {
    h ^= value + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
  }
  return static_cast<std::size_t>(h);
}

const TileWork& Scene::tileWork(std::uint64_t frame, const TileRect& rect) const {
  if (loopFrames_ > 0) frame %= loopFrames_;  // the same camera: the same walk
  const Key key{frame, rect.x(), rect.y(), rect.width(), rect.height()};
  {
    const std::lock_guard lock(mutex_);
    if (const auto found = memo_.find(key); found != memo_.end()) return found->second;
  }
  // Traversed outside the lock; two threads may both compute a tile, with the
  // same result, and the first one stored wins.
  const traverse::TraversalResult result =
      traverse::traverseTile(*culling_, cameras_.at(frame), rect, traversal_);
  TileWork work;
  work.needs = result.needs;
  work.boxes = result.needBoxes;
  work.splats = result.splats;
  work.cellsVisited = result.cellsVisited;
  work.ranges = result.ranges;
  const std::lock_guard lock(mutex_);
  return memo_.emplace(key, std::move(work)).first->second;
}

const std::vector<CellPrefix>& Scene::cellsInTile(std::uint64_t frame, const TileRect& rect) const {
  if (loopFrames_ > 0) frame %= loopFrames_;
  const Key key{frame, rect.x(), rect.y(), rect.width(), rect.height()};
  {
    const std::lock_guard lock(mutex_);
    if (const auto found = cellsMemo_.find(key); found != cellsMemo_.end()) return found->second;
  }
  auto cells =
      traverse::topLevelCellsInTile(*culling_, *layers_, cameras_.at(frame), rect, traversal_);
  const std::lock_guard lock(mutex_);
  return cellsMemo_.emplace(key, std::move(cells)).first->second;
}

std::uint64_t Scene::frameWorkingSetBytes(std::uint64_t frame, std::uint32_t gapSplats) const {
  const Camera& camera = cameras_.at(frame);
  const TileWork& work = tileWork(frame, fullFrameRect(camera));
  const traverse::TileWalk walk{work.needs, work.splats, work.ranges, work.boxes};
  return rangeSplats(traverse::needRanges(walk, 0, work.needs.size(), 0, work.ranges.size(),
                                          *layers_, gapSplats)) *
         sizeof(Splat);
}

double Scene::measureTraverseSecondsPerCell() const {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  std::uint64_t visited = 0;
  double seconds = 0.0;
  // Whole frames, repeated until the figure is worth something (>= 0.2 s).
  for (std::size_t round = 0; round < 1000 && (seconds < 0.2 || visited == 0); ++round) {
    const Camera& camera = cameras_[round % std::min<std::size_t>(cameras_.size(), 4)];
    visited +=
        traverse::traverseTile(*culling_, camera, fullFrameRect(camera), traversal_).cellsVisited;
    seconds = std::chrono::duration<double>(Clock::now() - start).count();
  }
  return visited > 0 ? seconds / static_cast<double>(visited) : 1e-7;
}

}  // namespace pointillist::simulator
