#include "render/raster/tile_renderer.hpp"

#include "common/errors.hpp"

namespace pointillist::render {

const char* splatModeName(SplatMode mode) {
  switch (mode) {
    case SplatMode::Splats:
      return "splats";
    case SplatMode::Blended:
      return "blended";
    case SplatMode::Instanced:
      return "instanced";
    case SplatMode::Statistical:
      return "statistical";
    case SplatMode::Points:
      break;
  }
  return "points";
}

SplatMode parseSplatMode(const std::string& name) {
  if (name == "points") return SplatMode::Points;
  if (name == "splats") return SplatMode::Splats;
  if (name == "blended") return SplatMode::Blended;
  if (name == "instanced") return SplatMode::Instanced;
  if (name == "statistical") return SplatMode::Statistical;
  throw UsageError("unknown render mode '" + name +
                   "' (points, splats, blended, instanced or statistical)");
}

DepthLinearizer::DepthLinearizer(const Camera& camera) {
  const auto nearPlane = static_cast<double>(camera.near_plane());
  const auto farDouble = static_cast<double>(camera.far_plane());
  numerator = static_cast<float>(farDouble * nearPlane);
  farPlane = camera.far_plane();
  range = static_cast<float>(farDouble - nearPlane);
}

SplatMode splatModeFromProto(v1::RenderMode mode) {
  switch (mode) {
    case v1::RENDER_MODE_POINTS:
      return SplatMode::Points;
    case v1::RENDER_MODE_SPLATS:
      return SplatMode::Splats;
    case v1::RENDER_MODE_BLENDED:
      return SplatMode::Blended;
    case v1::RENDER_MODE_INSTANCED:
      return SplatMode::Instanced;
    case v1::RENDER_MODE_STATISTICAL:
      return SplatMode::Statistical;
    default:
      throw UsageError("render mode " + v1::RenderMode_Name(mode) +
                       " is not drawn by the splat renderers");
  }
}

v1::RenderMode splatModeToProto(SplatMode mode) {
  switch (mode) {
    case SplatMode::Splats:
      return v1::RENDER_MODE_SPLATS;
    case SplatMode::Blended:
      return v1::RENDER_MODE_BLENDED;
    case SplatMode::Instanced:
      return v1::RENDER_MODE_INSTANCED;
    case SplatMode::Statistical:
      return v1::RENDER_MODE_STATISTICAL;
    case SplatMode::Points:
      break;
  }
  return v1::RENDER_MODE_POINTS;
}

}  // namespace pointillist::render
