#include "display/core/work_density.hpp"

#include <algorithm>
#include <cmath>

namespace pointillist::display {
namespace {

std::uint32_t cellsAlong(std::uint32_t pixels, std::uint32_t side) {
  return (pixels + side - 1) / side;
}

}  // namespace

WorkDensity::WorkDensity(std::uint32_t width, std::uint32_t height,
                         std::span<const TileFeedback> tiles, std::size_t maxCells,
                         std::uint32_t minCellSide) {
  rebuild(width, height, tiles, maxCells, minCellSide);
}

void WorkDensity::rebuild(std::uint32_t width, std::uint32_t height,
                          std::span<const TileFeedback> tiles, std::size_t maxCells,
                          std::uint32_t minCellSide) {
  width_ = width;
  height_ = height;
  cell_ = std::max(minCellSide, 1u);
  columns_ = 0;
  rows_ = 0;
  table_.clear();  // unmeasured until the table is filled
  if (width == 0 || height == 0) return;
  double measuredArea = 0.0;
  double measuredWork = 0.0;
  for (const TileFeedback& tile : tiles) {
    const double area = static_cast<double>(tile.rect.width()) * tile.rect.height();
    if (area <= 0.0) continue;
    measuredArea += area;
    measuredWork += static_cast<double>(tile.splats);
  }
  if (measuredArea <= 0.0 || measuredWork <= 0.0) return;

  while (static_cast<std::size_t>(cellsAlong(width, cell_)) * cellsAlong(height, cell_) >
         std::max<std::size_t>(maxCells, 1)) {
    ++cell_;
  }
  columns_ = cellsAlong(width, cell_);
  rows_ = cellsAlong(height, cell_);
  // Each cell's measured work and the area tiles measured in it; the buffers
  // stay from one frame to the next (a fresh 4K grid is 3000 pages to fault in).
  cells_.assign(static_cast<std::size_t>(columns_) * rows_, {0.0, 0.0});
  for (const TileFeedback& tile : tiles) {
    const std::uint32_t x0 = std::min(tile.rect.x(), width);
    const std::uint32_t y0 = std::min(tile.rect.y(), height);
    const std::uint32_t x1 = std::min(tile.rect.x() + tile.rect.width(), width);
    const std::uint32_t y1 = std::min(tile.rect.y() + tile.rect.height(), height);
    if (x1 <= x0 || y1 <= y0) continue;
    const double density = static_cast<double>(tile.splats) /
                           (static_cast<double>(tile.rect.width()) * tile.rect.height());
    for (std::uint32_t row = y0 / cell_; row * cell_ < y1; ++row) {
      const double h =
          static_cast<double>(std::min(y1, (row + 1) * cell_) - std::max(y0, row * cell_));
      for (std::uint32_t column = x0 / cell_; column * cell_ < x1; ++column) {
        const double w =
            static_cast<double>(std::min(x1, (column + 1) * cell_) - std::max(x0, column * cell_));
        const std::size_t index = static_cast<std::size_t>(row) * columns_ + column;
        cells_[index].work += density * w * h;
        cells_[index].covered += w * h;
      }
    }
  }
  const double mean = measuredWork / measuredArea;
  table_.assign(static_cast<std::size_t>(rows_ + 1) * (columns_ + 1), 0.0);
  for (std::uint32_t row = 0; row < rows_; ++row) {
    const double h = static_cast<double>(std::min(height, (row + 1) * cell_) - row * cell_);
    double rowSum = 0.0;
    for (std::uint32_t column = 0; column < columns_; ++column) {
      const double w = static_cast<double>(std::min(width, (column + 1) * cell_) - column * cell_);
      const std::size_t index = static_cast<std::size_t>(row) * columns_ + column;
      const double area = w * h;
      rowSum +=
          cells_[index].work + mean * (std::max(0.0, area - cells_[index].covered) + 0.02 * area);
      table_[static_cast<std::size_t>(row + 1) * (columns_ + 1) + column + 1] =
          table_[static_cast<std::size_t>(row) * (columns_ + 1) + column + 1] + rowSum;
    }
  }
}

double WorkDensity::below(double x, double y) const {
  // The table is bilinear within a cell, which is exact for uniform cells.
  const auto locate = [this](double at, std::uint32_t pixels, std::uint32_t cells) {
    at = std::clamp(at, 0.0, static_cast<double>(pixels));
    auto index = std::min(static_cast<std::uint32_t>(at / cell_), cells - 1);
    const double start = static_cast<double>(index * cell_);
    const double side = static_cast<double>(std::min(pixels, (index + 1) * cell_) - index * cell_);
    return std::pair{index, std::clamp((at - start) / side, 0.0, 1.0)};
  };
  const auto [column, fx] = locate(x, width_, columns_);
  const auto [row, fy] = locate(y, height_, rows_);
  const std::size_t stride = columns_ + 1;
  const double t00 = table_[row * stride + column];
  const double t01 = table_[row * stride + column + 1];
  const double t10 = table_[(row + 1) * stride + column];
  const double t11 = table_[(row + 1) * stride + column + 1];
  return t00 + fx * (t01 - t00) + fy * (t10 - t00) + fx * fy * (t11 - t01 - t10 + t00);
}

double WorkDensity::work(const TileRect& rect) const {
  const double area = static_cast<double>(rect.width()) * rect.height();
  if (!measured() || area <= 0.0) return area;
  const double x0 = rect.x();
  const double y0 = rect.y();
  const double x1 = x0 + rect.width();
  const double y1 = y0 + rect.height();
  return std::max(0.0, below(x1, y1) - below(x0, y1) - below(x1, y0) + below(x0, y0));
}

std::uint32_t WorkDensity::cutAt(const TileRect& rect, bool alongX, double share, std::uint32_t low,
                                 std::uint32_t high) const {
  const double goal = work(rect) * share;
  const auto part = [&](std::uint32_t offset) {
    return alongX ? makeTileRect(rect.x(), rect.y(), offset, rect.height())
                  : makeTileRect(rect.x(), rect.y(), rect.width(), offset);
  };
  // The low part's work grows with the offset: the first offset reaching the goal.
  while (low < high) {
    const std::uint32_t middle = low + (high - low) / 2;
    if (work(part(middle)) < goal) {
      low = middle + 1;
    } else {
      high = middle;
    }
  }
  return low;
}

}  // namespace pointillist::display
