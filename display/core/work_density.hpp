#pragma once
// Where on the screen the work of the last completed frame lay, for sizing the
// next frame's tiles: each tile's splats spread evenly over its rectangle,
// kept on a grid of small cells with a summed-area table, so the estimated
// work of any rectangle costs four lookups however many tiles measured it.
//
// Pixels no tile measured (the view moved onto new ground) count at the mean
// measured density: their work is unknown, not absent. Every pixel also gets
// 2 % of the mean density, so ground measured as empty can still be cut.
#include <cstdint>
#include <span>
#include <vector>

#include "common/camera.hpp"

namespace pointillist::display {

// What one tile of a completed frame took.
struct TileFeedback {
  TileRect rect;
  double seconds = 0.0;      // render time on its render process
  std::uint64_t splats = 0;  // splats drawn
};

class WorkDensity {
 public:
  // No measurement: work is proportional to area.
  WorkDensity() = default;
  // The frame is `width` x `height` pixels; cells are the smallest square
  // side of at least `minCellSide` pixels that keeps the grid within
  // `maxCells`.
  WorkDensity(std::uint32_t width, std::uint32_t height, std::span<const TileFeedback> tiles,
              std::size_t maxCells = 1u << 19, std::uint32_t minCellSide = 1);

  // The same as constructing it anew, reusing this one's buffers.
  void rebuild(std::uint32_t width, std::uint32_t height, std::span<const TileFeedback> tiles,
               std::size_t maxCells = 1u << 19, std::uint32_t minCellSide = 1);

  bool measured() const { return !table_.empty(); }
  std::uint32_t cellSide() const { return cell_; }
  // Estimated splats in `rect` (exact sums of whole cells; uniform within a cell).
  double work(const TileRect& rect) const;
  // Offset from the rectangle's low edge along `alongX` (else y) at which the
  // low part holds `share` of its work, in whole pixels within [low, high].
  std::uint32_t cutAt(const TileRect& rect, bool alongX, double share, std::uint32_t low,
                      std::uint32_t high) const;

 private:
  // Work in [0, x) x [0, y), x and y in pixels (fractional cells interpolated).
  double below(double x, double y) const;

  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  std::uint32_t cell_ = 1;
  std::uint32_t columns_ = 0;
  std::uint32_t rows_ = 0;
  std::vector<double> table_;  // (rows_ + 1) x (columns_ + 1) summed-area table
  struct Cell {
    double work = 0.0;
    double covered = 0.0;
  };
  std::vector<Cell> cells_;  // rebuild's scratch
};

}  // namespace pointillist::display
