#pragma once
// What a run looks at and how: shared by the display and the reference
// renderer so both see exactly the same frames from the same options.
#include <CLI/CLI.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "common/camera_path.hpp"
#include "common/dataset.hpp"
#include "common/run_settings.hpp"
#include "pointillist.pb.h"

namespace pointillist {

struct ViewOptions {
  std::string cameraPath = "orbit";
  std::uint32_t frames = 24;
  // The path played this many times over: a turntable. Later loops find
  // every view's data already sent, so steady state is then the later loops.
  std::uint32_t loops = 1;
  std::string size = "1280x720";
  std::string mode = "points";
  std::string up = "auto";
  float lodPixels = 1.0f;
  float sizeScale = 1.0f;
  bool noBackfaceCull = false;
  bool unlit = false;             // flat colours: no headlight shading
  std::string renderer = "auto";  // auto | gl | cpu
  bool edl = false;               // eye-dome lighting from the depth buffer
  float edlStrength = kDefaultEdlStrength;
  float edlRadius = kDefaultEdlRadius;  // pixels
};

void addViewOptions(CLI::App& app, ViewOptions& options);

// points | splats | blended | instanced | statistical
v1::RenderMode parseRenderMode(const std::string& name);
const char* renderModeName(v1::RenderMode mode);  // parseRenderMode's names
// With --edl: checkEdl for the options' mode, strength and radius.
void checkViewEdl(const ViewOptions& options);
glm::vec3 parseUpAxis(const std::string& name, const SceneBounds& bounds);
SceneBounds datasetBounds(const DatasetManifest& manifest);

// The cameras of a run: one per frame of the path.
std::vector<Camera> viewCameras(const ViewOptions& options, const SceneBounds& bounds);

}  // namespace pointillist
