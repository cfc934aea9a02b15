// pointillist-bench-render-cache: the render cache (seed 001) alone, on one
// core: how long a reprojection and an insert take for a given frame size.
// Not a test.
//
// The scene is a toy city cast by rays here (a ground plane with blocks of
// random heights; the sky is background), seen from a camera circling it.
// --frames final frames along the circle go into the cache, as a person
// turning the view would send them, then the camera just past the last one is
// reprojected --reps times; the median and the least time are printed with
// what the interim frame holds. --coverage keeps that share of each frame's
// columns (the rest is sky), for views that are mostly background.
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include <glm/gtc/matrix_inverse.hpp>

#include "common/camera.hpp"
#include "common/camera_path.hpp"
#include "common/clock.hpp"
#include "common/image.hpp"
#include "display/core/render_cache.hpp"

namespace pointillist::display {
namespace {

constexpr float kBlockPitch = 10.0f;  // street grid, world units
constexpr float kCityHalfWidth = 300.0f;

// Height of the city at (x, y): blocks of hashed heights between streets.
float cityHeight(float x, float y) {
  const auto bx = static_cast<int>(std::floor(x / kBlockPitch));
  const auto by = static_cast<int>(std::floor(y / kBlockPitch));
  const float fx = x - static_cast<float>(bx) * kBlockPitch;
  const float fy = y - static_cast<float>(by) * kBlockPitch;
  if (fx < 2.0f || fy < 2.0f) return 0.0f;  // street
  const unsigned hash =
      static_cast<unsigned>(bx) * 73856093u ^ static_cast<unsigned>(by) * 19349663u;
  return static_cast<float>((hash >> 4) % 30u);
}

struct Frame {
  Image image;
  std::vector<float> depth;
};

// Marches each pixel's ray until it enters a block or the ground.
Frame castFrame(const Camera& camera, double coverage) {
  const std::uint32_t width = camera.image_width();
  const std::uint32_t height = camera.image_height();
  Frame frame{
      Image(width, height, {0, 0, 0, 255}),
      std::vector<float>(std::size_t{width} * height, std::numeric_limits<float>::infinity())};
  const glm::mat4 inverse = glm::inverse(viewProjectionMatrix(camera));
  const glm::vec3 eye = cameraEye(camera);
  const glm::vec3 forward = glm::normalize(cameraTarget(camera) - eye);
  const auto coveredColumns = static_cast<std::uint32_t>(coverage * width);
  for (std::uint32_t y = 0; y < height; ++y) {
    for (std::uint32_t x = 0; x < coveredColumns; ++x) {
      const float ndcX = 2.0f * (static_cast<float>(x) + 0.5f) / static_cast<float>(width) - 1.0f;
      const float ndcY = 2.0f * (static_cast<float>(y) + 0.5f) / static_cast<float>(height) - 1.0f;
      const glm::vec4 far = inverse * glm::vec4(ndcX, ndcY, 1.0f, 1.0f);
      const glm::vec3 direction = glm::normalize(glm::vec3(far) / far.w - eye);
      if (direction.z >= 0.0f) continue;  // sky
      // Start where the ray comes down to the tallest block.
      float t = std::max(0.0f, (eye.z - 30.0f) / -direction.z);
      const float end = eye.z / -direction.z;
      glm::vec3 at = eye + t * direction;
      while (t <= end && at.z > cityHeight(at.x, at.y)) {
        t += 0.5f;
        at = eye + t * direction;
      }
      if (t > end) at = eye + end * direction;
      if (std::abs(at.x) > kCityHalfWidth || std::abs(at.y) > kCityHalfWidth) continue;
      frame.depth[std::size_t{y} * width + x] = glm::dot(at - eye, forward);
      frame.image.set(x, y,
                      {static_cast<std::uint8_t>(static_cast<int>(at.x * 4.0f) & 255),
                       static_cast<std::uint8_t>(static_cast<int>(at.y * 4.0f) & 255),
                       static_cast<std::uint8_t>(std::min(255.0f, at.z * 8.0f)), 255});
    }
  }
  return frame;
}

Camera circlingCamera(float angle, std::uint32_t width, std::uint32_t height) {
  const glm::vec3 eye{120.0f * std::sin(angle), -120.0f * std::cos(angle), 60.0f};
  return makeCamera(eye, {0, 0, 0}, {0, 0, 1}, 45.0f, 1.0f, 1000.0f, width, height);
}

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values.empty() ? 0.0 : values[values.size() / 2];
}

int run(int argc, char** argv) {
  CLI::App app{"pointillist-bench-render-cache: render cache reprojection and insert, one core"};
  std::string size = "1280x720";
  int frames = 6;
  int reps = 50;
  double coverage = 1.0;
  float stepDegrees = 1.7f;
  app.add_option("--size", size, "Frame size WxH")->capture_default_str();
  app.add_option("--frames", frames, "Final frames inserted first")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--reps", reps, "Reprojections timed")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--coverage", coverage, "Share of each frame's columns with the city")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--step-degrees", stepDegrees, "Camera turn between frames")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  const auto [width, height] = parseImageSize(size);
  const float step = stepDegrees * 3.14159265f / 180.0f;
  RenderCache cache;
  std::vector<double> insertMs;
  for (int i = 0; i < frames; ++i) {
    const Camera camera = circlingCamera(step * static_cast<float>(i), width, height);
    const Frame frame = castFrame(camera, coverage);
    const auto start = Clock::now();
    cache.insert(camera, frame.image, frame.depth);
    insertMs.push_back(secondsBetween(start, Clock::now()) * 1000.0);
  }
  const Camera next = circlingCamera(step * (static_cast<float>(frames) - 0.5f), width, height);
  std::vector<double> reprojectMs;
  InterimFrame interim;
  for (int i = 0; i < reps; ++i) {
    interim = cache.reproject(next);
    reprojectMs.push_back(interim.seconds * 1000.0);
  }
  const auto pixels = static_cast<double>(interim.pixels());
  std::printf("render cache, %ux%u, %zu points after %d frames (coverage %.2f)\n", width, height,
              cache.size(), frames, coverage);
  std::printf("reproject: median %.2f ms, least %.2f ms over %d\n", median(reprojectMs),
              *std::min_element(reprojectMs.begin(), reprojectMs.end()), reps);
  std::printf("insert: median %.2f ms over %d frames\n", median(insertMs), frames);
  std::printf("interim: %.1f %% samples, %.1f %% interpolated, %.1f %% holes, %llu culled\n",
              100.0 * static_cast<double>(interim.samples) / pixels,
              100.0 * static_cast<double>(interim.dense + interim.sparse) / pixels,
              100.0 * static_cast<double>(interim.holes) / pixels,
              static_cast<unsigned long long>(interim.culled));
  return 0;
}

}  // namespace
}  // namespace pointillist::display

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-bench-render-cache",
                                  [&] { return pointillist::display::run(argc, argv); });
}
