#include "simulator/lit_pixels.hpp"

#include <bit>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "common/image_compression.hpp"
#include "common/pixel_runs.hpp"
#include "render/raster/cpu_point_renderer.hpp"

namespace pointillist::simulator {

FrameCoverage::FrameCoverage(std::span<const std::uint64_t> words, std::uint32_t width,
                             std::uint32_t height, std::uint64_t empty)
    : width_(width), height_(height), rowWords_((std::size_t{width} + 63) / 64) {
  if (words.size() != std::size_t{width} * height)
    throw Error("internal error: a frame's coverage needs width x height words");
  bits_.assign(rowWords_ * height, 0);
  for (std::uint32_t y = 0; y < height; ++y) {
    const std::uint64_t* row = words.data() + std::size_t{y} * width;
    std::uint64_t* out = bits_.data() + std::size_t{y} * rowWords_;
    for (std::uint32_t x = 0; x < width; ++x)
      out[x / 64] |= std::uint64_t{row[x] != empty ? 1u : 0u} << (x % 64);
  }
  for (const std::uint64_t w : bits_) lit_ += static_cast<std::uint64_t>(std::popcount(w));
}

LitRuns FrameCoverage::count(const TileRect& box) const {
  const std::uint32_t x0 = std::min(box.x(), width_), y0 = std::min(box.y(), height_);
  const auto x1 = static_cast<std::uint32_t>(
      std::min<std::uint64_t>(std::uint64_t{box.x()} + box.width(), width_));
  const auto y1 = static_cast<std::uint32_t>(
      std::min<std::uint64_t>(std::uint64_t{box.y()} + box.height(), height_));
  LitRuns out;
  if (x0 >= x1 || y0 >= y1) return out;
  for (std::uint32_t y = y0; y < y1; ++y) {
    const std::uint64_t* row = bits_.data() + std::size_t{y} * rowWords_;
    // Word by word: lit bits, and run starts (lit with no lit pixel before
    // it in the box's row).
    bool before = false;
    for (std::uint32_t at = x0; at < x1;) {
      const std::uint32_t word = at / 64, first = at % 64;
      const std::uint32_t last = std::min<std::uint32_t>(64, first + (x1 - at));  // exclusive
      const std::uint64_t keep = (last == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << last) - 1) &
                                 (~std::uint64_t{0} << first);
      const std::uint64_t bits = row[word] & keep;
      const std::uint64_t previous = (bits << 1) | (before ? std::uint64_t{1} << first : 0);
      out.lit += static_cast<std::uint64_t>(std::popcount(bits));
      out.runs += static_cast<std::uint64_t>(std::popcount(bits & ~previous));
      before = ((bits >> (last - 1)) & 1u) != 0;
      at += last - first;
    }
  }
  // Empty pixels at the box's end go as one more run of none.
  if (!bit(x1 - 1, y1 - 1)) ++out.runs;
  return out;
}

double measureCompression(std::span<const std::byte> frame, std::size_t pixelBytes,
                          std::uint32_t width, std::uint32_t height,
                          std::span<const std::byte> empty, int level) {
  std::uint64_t plain = 0, compressed = 0;
  for (std::uint32_t y = 0; y < height; y += kCompressionBlock) {
    for (std::uint32_t x = 0; x < width; x += kCompressionBlock) {
      const PixelBox box{x, y, std::min(kCompressionBlock, width - x),
                         std::min(kCompressionBlock, height - y)};
      const std::vector<std::byte> runs = encodePixelRuns(frame, pixelBytes, width, box, empty);
      // Runs of an empty box are one run of none: no image travels.
      if (runs.size() <= 8) continue;
      const std::vector<std::byte> packed = compressImageBytes(runs, level);
      plain += runs.size();
      compressed += packed.empty() ? runs.size() : packed.size();
    }
  }
  return compressed > 0 ? static_cast<double>(plain) / static_cast<double>(compressed) : 1.0;
}

LitPixels::LitPixels(const Dataset& dataset, std::span<const Camera> cameras,
                     const traverse::TraversalSettings& traversal, unsigned threads,
                     int compressionLevel)
    : cameras_(cameras.begin(), cameras.end()),
      traversal_(traversal),
      compressionLevel_(compressionLevel),
      renderer_(std::make_unique<render::CpuPointRenderer>(std::max(threads, 1u))),
      frames_(cameras.size()) {
  if (dataset.hasStatistical())
    throw UsageError("the CPU point kernel draws no statistical packets (--lit-pixels off)");
  for (std::uint32_t cell = 0; cell < dataset.topLevelCells().size(); ++cell)
    renderer_->uploadCell(cell, dataset.packet(cell));
}

LitPixels::~LitPixels() = default;

const FrameCoverage& LitPixels::frame(std::uint64_t frame,
                                      const traverse::CullingTable& culling) const {
  const std::lock_guard lock(mutex_);
  std::unique_ptr<FrameCoverage>& slot = frames_.at(frame);
  if (slot) return *slot;
  const Camera& camera = cameras_[frame];
  const TileRect rect = fullFrameRect(camera);
  const traverse::TraversalResult walk = traverse::traverseTile(culling, camera, rect, traversal_);
  std::vector<render::DrawRange> ranges;
  ranges.reserve(walk.ranges.size());
  // Points mode, as the CPU kernel draws: an instanced section's records are
  // not splats.
  for (const auto& range : walk.ranges)
    if (!range.section) ranges.push_back({range.topLevel, range.offset, range.count, false});
  render::RenderSettings settings;
  settings.sizeScale = traversal_.sizeScale;
  renderer_->render(camera, rect, ranges, settings);
  slot = std::make_unique<FrameCoverage>(renderer_->pointWords(), rect.width(), rect.height(),
                                         render::kEmptyPixel);
  if (compressionLevel_ != 0) {
    constexpr std::uint64_t kEmpty = render::kEmptyPixel;
    slot->setCompression(
        measureCompression(std::as_bytes(renderer_->pixels()), 4, rect.width(), rect.height(),
                           std::as_bytes(std::span(kFrameBackground)), compressionLevel_),
        measureCompression(std::as_bytes(renderer_->pointWords()), 8, rect.width(), rect.height(),
                           std::as_bytes(std::span(&kEmpty, 1)), compressionLevel_));
  }
  return *slot;
}

}  // namespace pointillist::simulator
