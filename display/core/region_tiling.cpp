#include "display/core/region_tiling.hpp"

#include <algorithm>

namespace pointillist::display {
namespace {

constexpr std::uint8_t kAcrossX = 1;
constexpr std::uint8_t kAcrossY = 2;
// A cut keeps its axis until the other side is this much longer: flipping it
// moves every region below it, and with them their render processes' data.
constexpr double kAxisHysteresis = 1.5;

}  // namespace

std::vector<TileRect> RegionTiling::split(const TileRect& area, std::uint32_t leaves,
                                          const WorkDensity& density, std::uint32_t minSide) {
  std::vector<TileRect> out(leaves, makeTileRect(area.x(), area.y(), 0, 0));
  if (leaves == 0) return out;
  if (leaves != leaves_) {
    leaves_ = leaves;
    axis_.assign(2 * static_cast<std::size_t>(leaves) - 1, 0);
  }
  splitNode(area, 0, leaves, 0, density, std::max<std::uint32_t>(minSide, 1), out);
  return out;
}

void RegionTiling::splitNode(const TileRect& rect, std::uint32_t first, std::uint32_t count,
                             std::uint32_t node, const WorkDensity& density, std::uint32_t minSide,
                             std::vector<TileRect>& out) {
  if (count == 1 || rect.width() == 0 || rect.height() == 0) {
    out[first] = rect;  // further leaves (a tiny area) keep their empty rectangles
    return;
  }
  const std::uint32_t low = count / 2;
  const std::uint32_t high = count - low;

  std::uint8_t& axis = axis_[node];
  const double width = rect.width();
  const double height = rect.height();
  if (axis == 0 || (axis == kAcrossX && height > kAxisHysteresis * width) ||
      (axis == kAcrossY && width > kAxisHysteresis * height)) {
    axis = width >= height ? kAcrossX : kAcrossY;
  }
  // A side of one pixel cannot be cut: use the other.
  if (axis == kAcrossX && rect.width() < 2) axis = kAcrossY;
  if (axis == kAcrossY && rect.height() < 2) axis = kAcrossX;
  const bool acrossX = axis == kAcrossX;
  const std::uint32_t length = acrossX ? rect.width() : rect.height();
  if (length < 2) {
    out[first] = rect;
    return;
  }
  // Each side gets minSide, or its share of the length when that is less.
  const auto floorFor = [&](std::uint32_t leavesOnSide) {
    const auto share = static_cast<std::uint32_t>(std::uint64_t{length} * leavesOnSide / count);
    return std::clamp<std::uint32_t>(std::min(minSide, share), 1, length - 1);
  };
  const std::uint32_t lowest = floorFor(low);
  const std::uint32_t highest = length - floorFor(high);
  const std::uint32_t offset =
      lowest >= highest
          ? lowest
          : density.cutAt(rect, acrossX, static_cast<double>(low) / count, lowest, highest);
  const TileRect lowRect = acrossX ? makeTileRect(rect.x(), rect.y(), offset, rect.height())
                                   : makeTileRect(rect.x(), rect.y(), rect.width(), offset);
  const TileRect highRect =
      acrossX ? makeTileRect(rect.x() + offset, rect.y(), rect.width() - offset, rect.height())
              : makeTileRect(rect.x(), rect.y() + offset, rect.width(), rect.height() - offset);
  splitNode(lowRect, first, low, node + 1, density, minSide, out);
  splitNode(highRect, first + low, high, node + 2 * low, density, minSide, out);
}

}  // namespace pointillist::display
