#include "common/camera_path.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>

#include "common/errors.hpp"

namespace pointillist {
namespace {

constexpr float kPi = 3.14159265358979f;

glm::vec3 centreOf(const SceneBounds& bounds) {
  return 0.5f * (bounds.min + bounds.max);
}
float radiusOf(const SceneBounds& bounds) {
  return std::max(0.5f * glm::length(bounds.max - bounds.min), 1e-3f);
}

// Eye for an orbit angle: like cameraForBounds, so paths frame the data alike.
CameraKey orbitKey(const SceneBounds& bounds, const glm::vec3& up, float azimuthDegrees,
                   float elevationDegrees, float distanceFactor, const glm::vec3& target) {
  const Camera camera = cameraForBounds(bounds.min, bounds.max, 16, 9, azimuthDegrees,
                                        elevationDegrees, distanceFactor, 45.0f, up);
  CameraKey key;
  key.eye = cameraEye(camera) - centreOf(bounds) + target;
  key.target = target;
  key.up = up;
  return key;
}

}  // namespace

std::vector<std::string> builtinCameraPaths() {
  return {"orbit", "flythrough", "closeup", "turns"};
}

bool isBuiltinCameraPath(const std::string& name) {
  const auto names = builtinCameraPaths();
  return std::find(names.begin(), names.end(), name) != names.end();
}

glm::vec3 defaultUpAxis(const SceneBounds& bounds) {
  const glm::vec3 extent = bounds.max - bounds.min;
  if (extent.z <= extent.x && extent.z <= extent.y) return {0.0f, 0.0f, 1.0f};
  return {0.0f, 1.0f, 0.0f};
}

std::vector<CameraKey> builtinCameraPath(const std::string& name, const SceneBounds& bounds,
                                         std::uint32_t frames, const glm::vec3& up) {
  if (frames == 0) throw UsageError("a camera path needs at least one frame");
  std::vector<CameraKey> keys;
  keys.reserve(frames);
  const glm::vec3 centre = centreOf(bounds);
  const float radius = radiusOf(bounds);
  for (std::uint32_t i = 0; i < frames; ++i) {
    const float t = frames == 1 ? 0.0f : static_cast<float>(i) / static_cast<float>(frames);
    if (name == "orbit") {
      keys.push_back(orbitKey(bounds, up, 30.0f + 360.0f * t, 30.0f, 0.8f, centre));
    } else if (name == "flythrough") {
      // From an overview down to a third of the bounding radius above the data,
      // turning a quarter while the target slides across the surface.
      const float s = frames == 1 ? 0.0f : static_cast<float>(i) / static_cast<float>(frames - 1);
      const float ease = 0.5f - 0.5f * std::cos(kPi * s);
      const float distance = 1.1f - 0.85f * ease;
      const float elevation = 35.0f - 20.0f * ease;
      const glm::vec3 slide = 0.25f * radius * std::sin(kPi * s) *
                              glm::normalize(glm::cross(up, glm::vec3(up.y, up.z, up.x)));
      keys.push_back(
          orbitKey(bounds, up, 60.0f + 90.0f * ease, elevation, distance, centre + slide));
    } else if (name == "closeup") {
      keys.push_back(orbitKey(bounds, up, 10.0f + 40.0f * t, 20.0f, 0.45f, centre));
    } else if (name == "turns") {
      // A person swinging the view: two swings of 40 degrees either way with
      // a nod and a little zoom, so consecutive frames differ by up to ten
      // degrees at 48 frames (the render cache's hard case).
      const float swing = std::sin(2.0f * kPi * 2.0f * t);
      const float nod = std::sin(2.0f * kPi * t);
      keys.push_back(orbitKey(bounds, up, 30.0f + 40.0f * swing, 25.0f + 10.0f * nod,
                              0.75f + 0.1f * std::cos(2.0f * kPi * t), centre));
    } else {
      throw UsageError("unknown camera path '" + name +
                       "' (built-in paths: orbit, flythrough, closeup, turns)");
    }
  }
  return keys;
}

std::vector<CameraKey> readCameraPath(const std::filesystem::path& file, const glm::vec3& up) {
  std::ifstream in(file);
  if (!in) throw InputError(file.string() + ": cannot open camera path");
  std::vector<CameraKey> keys;
  std::string line;
  std::size_t lineNumber = 0;
  while (std::getline(in, line)) {
    ++lineNumber;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream fields(line);
    std::vector<float> values;
    std::string token;
    while (fields >> token) {
      char* end = nullptr;
      const float value = std::strtof(token.c_str(), &end);
      if (end == token.c_str() || *end != '\0' || !std::isfinite(value)) {
        throw InputError(file.string() + ": line " + std::to_string(lineNumber) + ": '" + token +
                         "' is not a finite number");
      }
      values.push_back(value);
    }
    if (values.empty()) continue;
    if (values.size() != 6 && values.size() != 9 && values.size() != 10) {
      throw InputError(file.string() + ": line " + std::to_string(lineNumber) +
                       ": expected 6, 9 or 10 numbers (eye, target, [up, [fovY]]), found " +
                       std::to_string(values.size()));
    }
    CameraKey key;
    key.eye = {values[0], values[1], values[2]};
    key.target = {values[3], values[4], values[5]};
    key.up = values.size() >= 9 ? glm::vec3(values[6], values[7], values[8]) : up;
    if (values.size() == 10) key.fovYDegrees = values[9];
    if (glm::length(key.eye - key.target) <= 0.0f) {
      throw InputError(file.string() + ": line " + std::to_string(lineNumber) +
                       ": eye and target coincide");
    }
    if (glm::length(glm::cross(key.up, key.target - key.eye)) <= 0.0f) {
      throw InputError(file.string() + ": line " + std::to_string(lineNumber) +
                       ": up is parallel to the view direction");
    }
    if (!(key.fovYDegrees > 0.0f && key.fovYDegrees < 180.0f)) {
      throw InputError(file.string() + ": line " + std::to_string(lineNumber) +
                       ": field of view must be in (0, 180) degrees");
    }
    keys.push_back(key);
  }
  if (keys.empty()) throw InputError(file.string() + ": camera path has no cameras");
  return keys;
}

void writeCameraPath(const std::filesystem::path& file, const std::vector<CameraKey>& keys) {
  std::ofstream out(file);
  if (!out) throw InputError(file.string() + ": cannot write camera path");
  out << "# eye(x y z) target(x y z) up(x y z) fovY\n" << std::setprecision(9);
  for (const CameraKey& key : keys) {
    out << key.eye.x << ' ' << key.eye.y << ' ' << key.eye.z << ' ' << key.target.x << ' '
        << key.target.y << ' ' << key.target.z << ' ' << key.up.x << ' ' << key.up.y << ' '
        << key.up.z << ' ' << key.fovYDegrees << '\n';
  }
  if (!out) throw InputError(file.string() + ": write failed");
}

std::vector<CameraKey> loadCameraPath(const std::string& nameOrFile, const SceneBounds& bounds,
                                      std::uint32_t frames, const glm::vec3& up) {
  if (isBuiltinCameraPath(nameOrFile)) return builtinCameraPath(nameOrFile, bounds, frames, up);
  if (!std::filesystem::exists(nameOrFile)) {
    throw UsageError("camera path '" + nameOrFile +
                     "' is neither a file nor a built-in path (orbit, flythrough, closeup, turns)");
  }
  return readCameraPath(nameOrFile, up);
}

Camera cameraFromKey(const CameraKey& key, const SceneBounds& bounds, std::uint32_t width,
                     std::uint32_t height) {
  const float radius = radiusOf(bounds);
  const float distance = glm::length(centreOf(bounds) - key.eye);
  const float farPlane = distance + radius * 1.05f;
  const float nearPlane = std::max(distance - radius * 1.05f, farPlane * 1e-4f);
  return makeCamera(key.eye, key.target, key.up, key.fovYDegrees, nearPlane, farPlane, width,
                    height);
}

std::pair<std::uint32_t, std::uint32_t> parseImageSize(const std::string& text) {
  const auto x = text.find('x');
  try {
    if (x == std::string::npos) throw std::invalid_argument(text);
    std::size_t used = 0;
    const unsigned long width = std::stoul(text.substr(0, x), &used);
    if (used != x) throw std::invalid_argument(text);
    const unsigned long height = std::stoul(text.substr(x + 1), &used);
    if (used != text.size() - x - 1) throw std::invalid_argument(text);
    if (width == 0 || height == 0 || width > 16384 || height > 16384) throw std::out_of_range(text);
    return {static_cast<std::uint32_t>(width), static_cast<std::uint32_t>(height)};
  } catch (const std::logic_error&) {
    throw UsageError("image size '" + text +
                     "' is not WxH with 1..16384 pixels per side (e.g. 1280x720)");
  }
}

}  // namespace pointillist
