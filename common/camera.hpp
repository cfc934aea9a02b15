#pragma once
// Camera math every process shares: matrices from a v1::Camera, the tile
// projection (an off-centre frustum for a pixel rectangle of the frame), tile
// frustum planes for conservative culling, and screen-size estimates for level
// of detail. Conventions: right-handed world, GL clip space (NDC z in [-1,1]),
// window pixels with the origin at the bottom-left of the frame, pixel (x, y)
// covering [x, x+1) x [y, y+1) with its centre at (x + 0.5, y + 0.5).
#include <array>
#include <cstdint>

#include <glm/glm.hpp>

#include "pointillist.pb.h"

namespace pointillist {

using v1::Camera;
using v1::TileRect;

// Builds a camera; fovYDegrees is the full vertical field of view.
Camera makeCamera(const glm::vec3& eye, const glm::vec3& target, const glm::vec3& up,
                  float fovYDegrees, float nearPlane, float farPlane, std::uint32_t width,
                  std::uint32_t height);

// Throws UsageError naming the problem: zero image size, fov outside (0, 180),
// near <= 0, far <= near, eye == target, up parallel to the view direction,
// non-finite values.
void validateCamera(const Camera& camera);

glm::vec3 cameraEye(const Camera& camera);
glm::vec3 cameraTarget(const Camera& camera);

glm::mat4 viewMatrix(const Camera& camera);        // glm::lookAt (right-handed)
glm::mat4 projectionMatrix(const Camera& camera);  // glm::perspective, NDC z in [-1,1]
glm::mat4 viewProjectionMatrix(const Camera& camera);

TileRect fullFrameRect(const Camera& camera);
TileRect makeTileRect(std::uint32_t x, std::uint32_t y, std::uint32_t width, std::uint32_t height);
// The rectangle is non-empty and lies inside the camera's image.
bool tileInsideFrame(const Camera& camera, const TileRect& rect);
// Whether `inner` lies inside `outer`; a rect with a zero side lies anywhere.
bool rectWithin(const TileRect& inner, const TileRect& outer);

// Maps the frame's NDC to the tile's NDC: x' = x * W / rw + (W - 2 rx - rw) / rw,
// likewise for y; z and w unchanged. tileProjectionMatrix = this * projection:
// the off-centre frustum of the tile's pixel rectangle. (The renderer draws a
// tile with the full projection and a shifted viewport instead, which is the
// same mapping with bit-identical clip coordinates; see splat_renderer.hpp.)
glm::mat4 tileNdcTransform(const Camera& camera, const TileRect& rect);
glm::mat4 tileProjectionMatrix(const Camera& camera, const TileRect& rect);

// Window coordinates of a world point in the full frame: x, y in pixels
// (bottom-left origin), z the depth in [0,1] (glDepthRange(0,1)); w is the
// clip-space w (eye distance along the view axis; <= 0 behind the eye).
glm::vec4 projectToWindow(const Camera& camera, const glm::vec3& world);

// Frustum planes of a tile in world space: left, right, bottom, top, near,
// far. Each is (n, d) with unit n pointing inwards: dot(n, p) + d >= 0 inside.
// marginPixels grows the rectangle on every side. Culling for pixel-identical
// tiles: a splat's footprint can exceed its projected radius by rounding (a
// point of size s covers up to s/2 + 0.5 pixels from its centre, sizes are
// rounded, splats are at least 0.75 px in radius), so cull with
// sphereOutside(tilePlanes(camera, rect, 1.0f), centre, radius * sizeScale).
using FrustumPlanes = std::array<glm::vec4, 6>;
FrustumPlanes tilePlanes(const Camera& camera, const TileRect& rect, float marginPixels = 0.0f);
FrustumPlanes framePlanes(const Camera& camera);

// Signed distance of p to a plane (positive inside).
inline float planeDistance(const glm::vec4& plane, const glm::vec3& p) {
  return plane.x * p.x + plane.y * p.y + plane.z * p.z + plane.w;
}

// Conservative: true only when the sphere lies entirely outside one plane, so
// a sphere that straddles a tile border is never culled.
bool sphereOutside(const FrustumPlanes& planes, const glm::vec3& centre, float radius);
// Same for an axis-aligned box (tests the box corner farthest along each normal).
bool boxOutside(const FrustumPlanes& planes, const glm::vec3& boxMin, const glm::vec3& boxMax);
// boxOutside for a walk down a hierarchy of nested boxes: planes whose bits
// are set in `inside` (an enclosing box lies wholly inside them) are not
// tested. Returns -1 when the box is outside a plane, else `inside` with the
// bits of the planes the box lies wholly inside (by a margin that covers the
// rounding of a nested box's own test).
int boxInsidePlanes(const FrustumPlanes& planes, const glm::vec3& boxMin, const glm::vec3& boxMax,
                    int inside);

// Pixels per world unit for a length facing the camera at eye-space depth
// `distance` (distance along the view axis): imageHeight / (2 tan(fovY / 2)) /
// distance. A splat of world radius r at that depth covers about
// 2 * r * pixelsPerUnit(...) pixels across.
float pixelsPerUnit(const Camera& camera, float distance);
// The focal length in pixels: pixelsPerUnit(camera, d) == focal / d. Loops over
// many cells take it once (a tangent per call is most of pixelsPerUnit's cost).
double focalLengthPixels(const Camera& camera);
// pixelsPerUnit from a focal length taken once; the same value, bit for bit.
inline float pixelsPerUnit(double focalPixels, float distance) {
  return static_cast<float>(focalPixels / static_cast<double>(distance));
}
// Projected radius in pixels of a world-space radius at eye-space depth `distance`.
float projectedRadiusPixels(const Camera& camera, float worldRadius, float distance);
// Eye-space depth (distance along the view axis) of a world point.
float viewDepth(const Camera& camera, const glm::vec3& world);

// A camera that frames the box [boundsMin, boundsMax]: it looks at the box
// centre from direction (cos(el) cos(az), cos(el) sin(az), sin(el)) in the
// frame where `up` is the third axis (up = +z: azimuth 0 puts the eye on the +x
// side; up = +y: on the +z side), at the distance where the bounding sphere just
// fits the narrower field of view, times distanceFactor (< 1 zooms in).
// Near/far enclose the sphere (near stays > 0 when the eye is inside it).
Camera cameraForBounds(const glm::vec3& boundsMin, const glm::vec3& boundsMax, std::uint32_t width,
                       std::uint32_t height, float azimuthDegrees = 30.0f,
                       float elevationDegrees = 20.0f, float distanceFactor = 1.0f,
                       float fovYDegrees = 45.0f, const glm::vec3& up = glm::vec3(0, 0, 1));

}  // namespace pointillist
