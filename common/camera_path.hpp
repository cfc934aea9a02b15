#pragma once
// Camera paths for scripted runs and benchmarks: a text file, or a built-in
// path generated from the data's bounds.
//
// File format: one camera per line, '#' starts a comment, numbers separated by
// spaces:  ex ey ez  tx ty tz  [ux uy uz  [fovY]]
// (eye, target, up, vertical field of view in degrees; defaults up = the
// path's up axis, fovY = 45). Near and far planes are derived from the bounds.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "common/camera.hpp"

namespace pointillist {

struct CameraKey {
  glm::vec3 eye{0.0f};
  glm::vec3 target{0.0f};
  glm::vec3 up{0.0f, 0.0f, 1.0f};
  float fovYDegrees = 45.0f;
};

struct SceneBounds {
  glm::vec3 min{0.0f};
  glm::vec3 max{0.0f};
};

// Names of the built-in paths: "orbit" (a full turn around the data),
// "flythrough" (descends from an overview to close over the surface),
// "closeup" (a slow pan close to the surface).
std::vector<std::string> builtinCameraPaths();
bool isBuiltinCameraPath(const std::string& name);

// The default up axis for data: the axis along which the bounds are thinnest
// when that is z, else y (scans and meshes are usually y-up; terrain z-up).
glm::vec3 defaultUpAxis(const SceneBounds& bounds);

std::vector<CameraKey> builtinCameraPath(const std::string& name, const SceneBounds& bounds,
                                         std::uint32_t frames, const glm::vec3& up);
// Throws InputError naming the file and line for malformed lines or an empty path.
std::vector<CameraKey> readCameraPath(const std::filesystem::path& file, const glm::vec3& up);
void writeCameraPath(const std::filesystem::path& file, const std::vector<CameraKey>& keys);

// A built-in name or a file; `frames` applies to built-ins (files give their own count).
std::vector<CameraKey> loadCameraPath(const std::string& nameOrFile, const SceneBounds& bounds,
                                      std::uint32_t frames, const glm::vec3& up);

// The camera for a key: near and far planes enclose the bounds as seen from the eye.
Camera cameraFromKey(const CameraKey& key, const SceneBounds& bounds, std::uint32_t width,
                     std::uint32_t height);

// Parses "WxH" (e.g. 1280x720); throws UsageError otherwise.
std::pair<std::uint32_t, std::uint32_t> parseImageSize(const std::string& text);

}  // namespace pointillist
