#pragma once
// A reactive screen split in the style of Equalizer's load equalizer: one strip
// of the box of interest per render process, the strip borders moved after
// every frame so that each strip's measured render time approaches the mean.
#include <cstdint>
#include <vector>

#include "common/camera.hpp"

namespace pointillist::display {

class LoadEqualizer {
 public:
  // damping: share of the new split taken each frame (1 = jump straight to it).
  explicit LoadEqualizer(std::uint32_t strips, double damping = 0.5);

  // Strips covering `area` exactly once, split along its longer side in the
  // current proportions. Strip i goes to render process i.
  std::vector<TileRect> split(const TileRect& area) const;
  // Moves the borders from the strips' measured times (seconds, one per strip,
  // in the order split() returned them).
  void update(const std::vector<double>& stripSeconds);
  // Border positions in [0, 1], strips() + 1 of them.
  const std::vector<double>& borders() const { return borders_; }
  std::uint32_t strips() const { return static_cast<std::uint32_t>(borders_.size() - 1); }

 private:
  std::vector<double> borders_;
  double damping_;
};

}  // namespace pointillist::display
