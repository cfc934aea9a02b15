#include "display/core/load_equalizer.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "common/errors.hpp"

namespace pointillist::display {

LoadEqualizer::LoadEqualizer(std::uint32_t strips, double damping)
    : damping_(std::clamp(damping, 0.05, 1.0)) {
  if (strips == 0) throw UsageError("the load equalizer needs at least one strip");
  borders_.resize(strips + 1);
  for (std::uint32_t i = 0; i <= strips; ++i) {
    borders_[i] = static_cast<double>(i) / static_cast<double>(strips);
  }
}

std::vector<TileRect> LoadEqualizer::split(const TileRect& area) const {
  const bool alongX = area.width() >= area.height();
  const std::uint32_t length = alongX ? area.width() : area.height();
  std::vector<TileRect> tiles;
  std::uint32_t start = 0;
  for (std::uint32_t i = 0; i < strips(); ++i) {
    const std::uint32_t end =
        i + 1 == strips() ? length
                          : static_cast<std::uint32_t>(std::lround(borders_[i + 1] * length));
    const std::uint32_t clampedEnd = std::clamp(end, start, length);
    if (clampedEnd > start) {
      tiles.push_back(
          alongX ? makeTileRect(area.x() + start, area.y(), clampedEnd - start, area.height())
                 : makeTileRect(area.x(), area.y() + start, area.width(), clampedEnd - start));
    } else {
      tiles.push_back(makeTileRect(0, 0, 0, 0));  // an empty strip keeps indices aligned
    }
    start = clampedEnd;
  }
  return tiles;
}

void LoadEqualizer::update(const std::vector<double>& stripSeconds) {
  if (stripSeconds.size() != strips()) return;
  const double total = std::accumulate(stripSeconds.begin(), stripSeconds.end(), 0.0);
  if (!(total > 0.0)) return;
  // Time is taken as spread evenly inside each strip; place the new borders
  // where the accumulated time reaches k/n of the total.
  const std::uint32_t n = strips();
  const double minimumWidth = 0.25 / static_cast<double>(n);
  std::vector<double> target(n + 1, 0.0);
  target[n] = 1.0;
  double accumulated = 0.0;
  std::uint32_t strip = 0;
  for (std::uint32_t k = 1; k < n; ++k) {
    const double wanted = total * static_cast<double>(k) / static_cast<double>(n);
    while (strip < n && accumulated + stripSeconds[strip] < wanted) {
      accumulated += stripSeconds[strip++];
    }
    if (strip >= n) {
      target[k] = 1.0;
      continue;
    }
    const double fraction =
        stripSeconds[strip] > 0.0 ? (wanted - accumulated) / stripSeconds[strip] : 0.0;
    target[k] = borders_[strip] + fraction * (borders_[strip + 1] - borders_[strip]);
  }
  for (std::uint32_t k = 1; k < n; ++k) {
    borders_[k] = (1.0 - damping_) * borders_[k] + damping_ * target[k];
  }
  // Keep every strip at least a quarter of an even share wide, in order.
  for (std::uint32_t k = 1; k < n; ++k) {
    borders_[k] = std::max(borders_[k], borders_[k - 1] + minimumWidth);
  }
  for (std::uint32_t k = n - 1; k >= 1; --k) {
    borders_[k] = std::min(borders_[k], borders_[k + 1] - minimumWidth);
  }
}

}  // namespace pointillist::display
