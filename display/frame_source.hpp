#pragma once
// Where the display's frames come from when they are not a fixed camera path
// given at start-up: serve mode takes them from clients (ServiceFrameSource).
#include <cstddef>
#include <vector>

#include "common/camera.hpp"
#include "common/image.hpp"
#include "display/core/frame_assembly.hpp"

namespace pointillist::display {

// A frame to render: its camera and what it overrides of the run's settings.
struct FrameRequest {
  Camera camera;
  v1::FrameSettings settings;
  // Which tiles to draw first (serve mode's render cache); none: plan order.
  TilePriority tilePriority;
};

// A tile just composed into its frame.
struct ComposedTile {
  std::uint64_t frame = 0;  // in the order take() gave the cameras
  TileRect rect;
  std::uint32_t tilesDone = 0;  // of the frame, this one included
  std::uint32_t tiles = 0;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Frames to start now, at most `room`, in the order they follow.
  virtual std::vector<FrameRequest> take(std::size_t room) = 0;
  // True once no frame will be asked for any more; the run ends when the
  // frames already out are done.
  virtual bool finished() = 0;
  // A composed frame, in the order take() gave the cameras, with its
  // eye-space depth when its settings asked for tile depth (else empty).
  virtual void frameDone(const FinishedFrame& frame, Image image, std::vector<float> depth) = 0;
  // `composed`: the frame so far, this tile's pixels in it (serve mode's
  // interim frames show the tiles that came).
  virtual void tileComposed(const ComposedTile& /*tile*/, const Image& /*composed*/) {}
  // Every turn of the display's loop: what is due by time (interim frames).
  virtual void poll() {}
};

}  // namespace pointillist::display
