#include "common/camera.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include <glm/gtc/matrix_transform.hpp>

#include "common/errors.hpp"

namespace pointillist {

namespace {

glm::vec3 toVec3(const v1::Vec3& v) {
  return {v.x(), v.y(), v.z()};
}

void setVec3(v1::Vec3* out, const glm::vec3& v) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

bool finite(const glm::vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

// Planes in double: a tile a few pixels wide gives nearly parallel side planes
// whose float extraction would lose the sub-pixel accuracy culling needs.
FrustumPlanes planesFromMatrix(const glm::dmat4& m) {
  auto row = [&](int i) { return glm::dvec4(m[0][i], m[1][i], m[2][i], m[3][i]); };
  const glm::dvec4 r0 = row(0), r1 = row(1), r2 = row(2), r3 = row(3);
  const std::array<glm::dvec4, 6> raw = {r3 + r0, r3 - r0, r3 + r1, r3 - r1, r3 + r2, r3 - r2};
  FrustumPlanes planes{};
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const double len = glm::length(glm::dvec3(raw[i]));
    planes[i] = glm::vec4(raw[i] / len);
  }
  return planes;
}

glm::dmat4 tileNdcTransformD(const Camera& camera, const TileRect& rect, double margin = 0.0) {
  const double w = camera.image_width(), h = camera.image_height();
  const double rx = rect.x() - margin, ry = rect.y() - margin;
  const double rw = rect.width() + 2.0 * margin, rh = rect.height() + 2.0 * margin;
  glm::dmat4 t(1.0);
  t[0][0] = w / rw;
  t[1][1] = h / rh;
  t[3][0] = (w - 2.0 * rx - rw) / rw;
  t[3][1] = (h - 2.0 * ry - rh) / rh;
  return t;
}

glm::dmat4 projectionD(const Camera& camera) {
  const double aspect =
      static_cast<double>(camera.image_width()) / static_cast<double>(camera.image_height());
  return glm::perspectiveRH_NO(glm::radians(static_cast<double>(camera.fov_y_degrees())), aspect,
                               static_cast<double>(camera.near_plane()),
                               static_cast<double>(camera.far_plane()));
}

glm::dmat4 viewD(const Camera& camera) {
  return glm::lookAtRH(glm::dvec3(cameraEye(camera)), glm::dvec3(cameraTarget(camera)),
                       glm::dvec3(toVec3(camera.up())));
}

}  // namespace

Camera makeCamera(const glm::vec3& eye, const glm::vec3& target, const glm::vec3& up,
                  float fovYDegrees, float nearPlane, float farPlane, std::uint32_t width,
                  std::uint32_t height) {
  Camera camera;
  setVec3(camera.mutable_eye(), eye);
  setVec3(camera.mutable_target(), target);
  setVec3(camera.mutable_up(), up);
  camera.set_fov_y_degrees(fovYDegrees);
  camera.set_near_plane(nearPlane);
  camera.set_far_plane(farPlane);
  camera.set_image_width(width);
  camera.set_image_height(height);
  return camera;
}

void validateCamera(const Camera& camera) {
  auto fail = [](const std::string& what) { throw UsageError("invalid camera: " + what); };
  if (camera.image_width() == 0 || camera.image_height() == 0) fail("image size is zero");
  if (camera.image_width() > 16384 || camera.image_height() > 16384) {
    fail("image larger than 16384 pixels");
  }
  const glm::vec3 eye = cameraEye(camera), target = cameraTarget(camera);
  const glm::vec3 up = toVec3(camera.up());
  if (!finite(eye) || !finite(target) || !finite(up)) fail("non-finite eye, target or up");
  const float fov = camera.fov_y_degrees();
  if (!(fov > 0.0f && fov < 180.0f)) fail("fov_y_degrees must be in (0, 180)");
  if (!(camera.near_plane() > 0.0f)) fail("near_plane must be > 0");
  if (!(camera.far_plane() > camera.near_plane()) || !std::isfinite(camera.far_plane())) {
    fail("far_plane must be finite and > near_plane");
  }
  const glm::vec3 dir = target - eye;
  if (glm::length(dir) <= 0.0f) fail("eye equals target");
  if (glm::length(up) <= 0.0f) fail("up is zero");
  if (glm::length(glm::cross(glm::normalize(dir), glm::normalize(up))) < 1e-6f) {
    fail("up is parallel to the view direction");
  }
}

glm::vec3 cameraEye(const Camera& camera) {
  return toVec3(camera.eye());
}
glm::vec3 cameraTarget(const Camera& camera) {
  return toVec3(camera.target());
}

glm::mat4 viewMatrix(const Camera& camera) {
  return glm::mat4(viewD(camera));
}
glm::mat4 projectionMatrix(const Camera& camera) {
  return glm::mat4(projectionD(camera));
}
glm::mat4 viewProjectionMatrix(const Camera& camera) {
  return glm::mat4(projectionD(camera) * viewD(camera));
}

TileRect fullFrameRect(const Camera& camera) {
  return makeTileRect(0, 0, camera.image_width(), camera.image_height());
}

TileRect makeTileRect(std::uint32_t x, std::uint32_t y, std::uint32_t width, std::uint32_t height) {
  TileRect rect;
  rect.set_x(x);
  rect.set_y(y);
  rect.set_width(width);
  rect.set_height(height);
  return rect;
}

bool tileInsideFrame(const Camera& camera, const TileRect& rect) {
  return rect.width() > 0 && rect.height() > 0 &&
         std::uint64_t{rect.x()} + rect.width() <= camera.image_width() &&
         std::uint64_t{rect.y()} + rect.height() <= camera.image_height();
}

bool rectWithin(const TileRect& inner, const TileRect& outer) {
  if (inner.width() == 0 || inner.height() == 0) return true;
  return inner.x() >= outer.x() && inner.y() >= outer.y() &&
         std::uint64_t{inner.x()} + inner.width() <= std::uint64_t{outer.x()} + outer.width() &&
         std::uint64_t{inner.y()} + inner.height() <= std::uint64_t{outer.y()} + outer.height();
}

glm::mat4 tileNdcTransform(const Camera& camera, const TileRect& rect) {
  return glm::mat4(tileNdcTransformD(camera, rect));
}

glm::mat4 tileProjectionMatrix(const Camera& camera, const TileRect& rect) {
  return glm::mat4(tileNdcTransformD(camera, rect) * projectionD(camera));
}

glm::vec4 projectToWindow(const Camera& camera, const glm::vec3& world) {
  const glm::dvec4 clip = projectionD(camera) * viewD(camera) * glm::dvec4(glm::dvec3(world), 1.0);
  const glm::dvec3 ndc = glm::dvec3(clip) / clip.w;
  return glm::vec4(static_cast<float>((ndc.x + 1.0) * 0.5 * camera.image_width()),
                   static_cast<float>((ndc.y + 1.0) * 0.5 * camera.image_height()),
                   static_cast<float>(ndc.z * 0.5 + 0.5), static_cast<float>(clip.w));
}

FrustumPlanes tilePlanes(const Camera& camera, const TileRect& rect, float marginPixels) {
  return planesFromMatrix(tileNdcTransformD(camera, rect, static_cast<double>(marginPixels)) *
                          projectionD(camera) * viewD(camera));
}

FrustumPlanes framePlanes(const Camera& camera) {
  return planesFromMatrix(projectionD(camera) * viewD(camera));
}

bool sphereOutside(const FrustumPlanes& planes, const glm::vec3& centre, float radius) {
  return std::any_of(planes.begin(), planes.end(),
                     [&](const glm::vec4& p) { return planeDistance(p, centre) < -radius; });
}

namespace {

// The box corner farthest along the plane's normal (`toward`), or nearest.
glm::vec3 boxCorner(const glm::vec4& p, const glm::vec3& boxMin, const glm::vec3& boxMax,
                    bool toward) {
  return {(p.x >= 0) == toward ? boxMax.x : boxMin.x, (p.y >= 0) == toward ? boxMax.y : boxMin.y,
          (p.z >= 0) == toward ? boxMax.z : boxMin.z};
}

}  // namespace

bool boxOutside(const FrustumPlanes& planes, const glm::vec3& boxMin, const glm::vec3& boxMax) {
  return std::any_of(planes.begin(), planes.end(), [&](const glm::vec4& p) {
    return planeDistance(p, boxCorner(p, boxMin, boxMax, true)) < 0.0f;
  });
}

int boxInsidePlanes(const FrustumPlanes& planes, const glm::vec3& boxMin, const glm::vec3& boxMax,
                    int inside) {
  for (std::size_t i = 0; i < planes.size(); ++i) {
    const int bit = 1 << i;
    if ((inside & bit) != 0) continue;
    const glm::vec4& p = planes[i];
    if (planeDistance(p, boxCorner(p, boxMin, boxMax, true)) < 0.0f) return -1;
    const glm::vec3 near = boxCorner(p, boxMin, boxMax, false);
    const float scale =
        std::abs(p.x * near.x) + std::abs(p.y * near.y) + std::abs(p.z * near.z) + std::abs(p.w);
    if (planeDistance(p, near) > 1e-5f * scale) inside |= bit;
  }
  return inside;
}

double focalLengthPixels(const Camera& camera) {
  return 0.5 * camera.image_height() /
         std::tan(glm::radians(static_cast<double>(camera.fov_y_degrees())) * 0.5);
}

float pixelsPerUnit(const Camera& camera, float distance) {
  return pixelsPerUnit(focalLengthPixels(camera), distance);
}

float projectedRadiusPixels(const Camera& camera, float worldRadius, float distance) {
  return worldRadius * pixelsPerUnit(camera, distance);
}

float viewDepth(const Camera& camera, const glm::vec3& world) {
  const glm::vec3 eye = cameraEye(camera);
  const glm::vec3 forward = glm::normalize(cameraTarget(camera) - eye);
  return glm::dot(world - eye, forward);
}

Camera cameraForBounds(const glm::vec3& boundsMin, const glm::vec3& boundsMax, std::uint32_t width,
                       std::uint32_t height, float azimuthDegrees, float elevationDegrees,
                       float distanceFactor, float fovYDegrees, const glm::vec3& up) {
  if (width == 0 || height == 0) throw UsageError("cameraForBounds: image size is zero");
  if (!(distanceFactor > 0.0f)) throw UsageError("cameraForBounds: distanceFactor must be > 0");
  if (glm::length(up) <= 0.0f) throw UsageError("cameraForBounds: up is zero");
  const glm::vec3 centre = 0.5f * (boundsMin + boundsMax);
  // Empty or point-like bounds still get a usable camera.
  const float radius = std::max(0.5f * glm::length(boundsMax - boundsMin), 1e-3f);

  // Frame with `up` as third axis: (x, y, up) for up = z, (z, x, up) for up = y.
  const glm::vec3 e3 = glm::normalize(up);
  const glm::vec3 a = std::abs(e3.z) > 0.9f ? glm::vec3(0, 1, 0) : glm::vec3(1, 0, 0);
  const glm::vec3 e1 = glm::normalize(glm::cross(a, e3));
  const glm::vec3 e2 = glm::cross(e3, e1);
  const float az = glm::radians(azimuthDegrees), el = glm::radians(elevationDegrees);
  const glm::vec3 dir =
      std::cos(el) * std::cos(az) * e1 + std::cos(el) * std::sin(az) * e2 + std::sin(el) * e3;

  const float aspect = static_cast<float>(width) / static_cast<float>(height);
  const float halfFovY = glm::radians(fovYDegrees) * 0.5f;
  const float halfFovX = std::atan(std::tan(halfFovY) * aspect);
  const float fitDistance = radius / std::sin(std::min(halfFovY, halfFovX));
  const float distance = fitDistance * distanceFactor;
  const glm::vec3 eye = centre + dir * distance;

  const float farPlane = distance + radius * 1.05f;
  const float nearPlane = std::max(distance - radius * 1.05f, farPlane * 1e-4f);
  // Looking along up: any perpendicular axis serves as up.
  const glm::vec3 viewUp = std::abs(glm::dot(dir, e3)) > 0.9999f ? e2 : e3;
  return makeCamera(eye, centre, viewUp, fovYDegrees, nearPlane, farPlane, width, height);
}

}  // namespace pointillist
