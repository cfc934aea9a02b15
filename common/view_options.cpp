#include "common/view_options.hpp"

#include "common/errors.hpp"

namespace pointillist {

void addViewOptions(CLI::App& app, ViewOptions& options) {
  app.add_option("--camera-path", options.cameraPath,
                 "Camera path file, or built-in: orbit, flythrough, closeup, turns");
  app.add_option("--frames", options.frames, "Frames for a built-in camera path");
  app.add_option("--loops", options.loops,
                 "Play the camera path this many times over (a turntable); with more than one, "
                 "figures after warm-up are also given for the loops after the first")
      ->check(CLI::Range(1u, 1000u));
  app.add_option("--size", options.size, "Frame size WxH");
  app.add_option("--mode", options.mode,
                 "Render mode: points (fast), splats (oriented disks from a geometry shader), "
                 "blended (the disks blended EWA-style: smooth, about 2.5 times splats' cost) or "
                 "instanced (points; full-detail cells drawn from the vertex and transformation "
                 "streams of a dataset built with --instanced) or statistical (points generated "
                 "from the PCA nodes of a view-dependent cut, a dataset built with --statistical)");
  app.add_option("--up", options.up, "Up axis of the data for built-in paths: auto, x, y, z");
  app.add_option("--lod-pixels", options.lodPixels,
                 "Use a cell's level-splats once its splats project to this radius in pixels");
  app.add_option("--size-scale", options.sizeScale, "Multiplies splat radii");
  app.add_flag("--no-backface-cull", options.noBackfaceCull, "Keep cells that face away");
  app.add_flag("--unlit", options.unlit,
               "Flat colours: no headlight shading from the splat normals");
  app.add_option("--renderer", options.renderer,
                 "What draws: cpu (a point kernel, points mode only), gl (OSMesa, every mode) or "
                 "auto (cpu for points, gl otherwise)");
  app.add_flag("--edl", options.edl,
               "Eye-dome lighting: darken pixels whose neighbours are nearer the eye, so shape "
               "shows without normals (points and splats; combines with the headlight, or "
               "alone with --unlit)");
  app.add_option("--edl-strength", options.edlStrength,
                 "Eye-dome lighting: how dark depth steps get (0-100]")
      ->capture_default_str();
  app.add_option("--edl-radius", options.edlRadius,
                 "Eye-dome lighting: distance of the 8 neighbours sampled, in pixels [1-16]")
      ->capture_default_str();
}

v1::RenderMode parseRenderMode(const std::string& name) {
  if (name == "points") return v1::RENDER_MODE_POINTS;
  if (name == "splats") return v1::RENDER_MODE_SPLATS;
  if (name == "blended") return v1::RENDER_MODE_BLENDED;
  if (name == "instanced") return v1::RENDER_MODE_INSTANCED;
  if (name == "statistical") return v1::RENDER_MODE_STATISTICAL;
  throw UsageError("render mode '" + name +
                   "' is not one of: points, splats, blended, instanced, statistical");
}

const char* renderModeName(v1::RenderMode mode) {
  switch (mode) {
    case v1::RENDER_MODE_SPLATS:
      return "splats";
    case v1::RENDER_MODE_BLENDED:
      return "blended";
    case v1::RENDER_MODE_STATISTICAL:
      return "statistical";
    case v1::RENDER_MODE_INSTANCED:
      return "instanced";
    default:
      return "points";
  }
}

void checkViewEdl(const ViewOptions& options) {
  if (options.edl) checkEdl(parseRenderMode(options.mode), options.edlStrength, options.edlRadius);
}

glm::vec3 parseUpAxis(const std::string& name, const SceneBounds& bounds) {
  if (name == "auto") return defaultUpAxis(bounds);
  if (name == "x") return {1, 0, 0};
  if (name == "y") return {0, 1, 0};
  if (name == "z") return {0, 0, 1};
  throw UsageError("--up '" + name + "' is not one of: auto, x, y, z");
}

SceneBounds datasetBounds(const DatasetManifest& manifest) {
  return {{manifest.boundsMin[0], manifest.boundsMin[1], manifest.boundsMin[2]},
          {manifest.boundsMax[0], manifest.boundsMax[1], manifest.boundsMax[2]}};
}

std::vector<Camera> viewCameras(const ViewOptions& options, const SceneBounds& bounds) {
  const auto [width, height] = parseImageSize(options.size);
  const auto keys =
      loadCameraPath(options.cameraPath, bounds, options.frames, parseUpAxis(options.up, bounds));
  if (options.loops == 0) throw UsageError("--loops must be at least 1");
  std::vector<Camera> cameras;
  cameras.reserve(keys.size() * options.loops);
  for (const auto& key : keys) cameras.push_back(cameraFromKey(key, bounds, width, height));
  for (std::size_t i = keys.size(); i < keys.size() * options.loops; ++i) {
    cameras.push_back(cameras[i - keys.size()]);
  }
  return cameras;
}

}  // namespace pointillist
