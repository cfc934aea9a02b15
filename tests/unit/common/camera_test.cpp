#include "common/camera.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "common/errors.hpp"

namespace pointillist {
namespace {

Camera testCamera() {
  return makeCamera({3.0f, -4.0f, 2.0f}, {0.2f, 0.1f, -0.3f}, {0, 0, 1}, 50.0f, 0.5f, 20.0f, 640,
                    360);
}

glm::vec3 tileNdc(const Camera& camera, const TileRect& rect, const glm::vec3& p) {
  const glm::vec4 clip = tileProjectionMatrix(camera, rect) * viewMatrix(camera) * glm::vec4(p, 1);
  return glm::vec3(clip) / clip.w;
}

TEST(Camera, TargetProjectsToFrameCentre) {
  const Camera camera = testCamera();
  const glm::vec4 w = projectToWindow(camera, cameraTarget(camera));
  EXPECT_NEAR(w.x, 320.0f, 1e-3f);
  EXPECT_NEAR(w.y, 180.0f, 1e-3f);
  EXPECT_GT(w.z, 0.0f);
  EXPECT_LT(w.z, 1.0f);
  EXPECT_NEAR(w.w, glm::length(cameraTarget(camera) - cameraEye(camera)), 1e-4f);
}

TEST(Camera, RightHandedAndUpIsUp) {
  // Looking down -y with z up: +x is to the right, +z up.
  const Camera camera = makeCamera({0, 5, 0}, {0, 0, 0}, {0, 0, 1}, 60, 0.1f, 100, 200, 100);
  EXPECT_LT(projectToWindow(camera, {1, 0, 0}).x, 100.0f);  // eye on +y: +x appears left
  EXPECT_GT(projectToWindow(camera, {-1, 0, 0}).x, 100.0f);
  EXPECT_GT(projectToWindow(camera, {0, 0, 1}).y, 50.0f);
  // Nearer points have smaller depth.
  EXPECT_LT(projectToWindow(camera, {0, 1, 0}).z, projectToWindow(camera, {0, -1, 0}).z);
}

TEST(Camera, TileProjectionIsTheFrameRectangle) {
  const Camera camera = testCamera();
  const TileRect rect = makeTileRect(100, 40, 130, 90);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.5f, 1.5f);
  for (int i = 0; i < 100; ++i) {
    const glm::vec3 p(u(rng), u(rng), u(rng));
    const glm::vec4 full = projectToWindow(camera, p);
    const glm::vec3 t = tileNdc(camera, rect, p);
    // Tile NDC -> tile pixels + tile origin == full-frame pixels.
    EXPECT_NEAR((t.x + 1.0f) * 0.5f * 130.0f + 100.0f, full.x, 2e-3f);
    EXPECT_NEAR((t.y + 1.0f) * 0.5f * 90.0f + 40.0f, full.y, 2e-3f);
    EXPECT_NEAR(t.z * 0.5f + 0.5f, full.z, 1e-5f);
  }
  // The full-frame rectangle gives the plain projection.
  const glm::mat4 a = tileProjectionMatrix(camera, fullFrameRect(camera));
  const glm::mat4 b = projectionMatrix(camera);
  for (int c = 0; c < 4; ++c) {
    for (int r = 0; r < 4; ++r) EXPECT_NEAR(a[c][r], b[c][r], 1e-6f);
  }
}

// A world point at full-frame window position (px, py) and eye depth `depth`.
glm::vec3 unproject(const Camera& camera, float px, float py, float depth) {
  const glm::mat4 inv = glm::inverse(viewProjectionMatrix(camera));
  const glm::vec2 ndc(px / static_cast<float>(camera.image_width()) * 2.0f - 1.0f,
                      py / static_cast<float>(camera.image_height()) * 2.0f - 1.0f);
  const glm::vec4 a = inv * glm::vec4(ndc, -1.0f, 1.0f);
  const glm::vec4 b = inv * glm::vec4(ndc, 1.0f, 1.0f);
  const glm::vec3 nearP = glm::vec3(a) / a.w, farP = glm::vec3(b) / b.w;
  const glm::vec3 eye = cameraEye(camera);
  const glm::vec3 forward = glm::normalize(cameraTarget(camera) - eye);
  const glm::vec3 dir = farP - nearP;
  const float t = (depth - glm::dot(nearP - eye, forward)) / glm::dot(dir, forward);
  return nearP + dir * t;
}

TEST(Camera, TilePlanesSeparateInsideFromOutside) {
  const Camera camera = testCamera();
  const TileRect rect = makeTileRect(200, 100, 64, 48);
  const FrustumPlanes planes = tilePlanes(camera, rect);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> depth(0.6f, 19.0f);
  std::uniform_real_distribution<float> fx(200.05f, 263.95f), fy(100.05f, 147.95f);
  std::uniform_real_distribution<float> gx(0.0f, 640.0f), gy(0.0f, 360.0f);
  for (int i = 0; i < 500; ++i) {
    const glm::vec3 inside = unproject(camera, fx(rng), fy(rng), depth(rng));
    EXPECT_FALSE(sphereOutside(planes, inside, 0.0f)) << i;
    const float x = gx(rng), y = gy(rng);
    const bool outsideRect = x < 199.9f || x > 264.1f || y < 99.9f || y > 148.1f;
    if (!outsideRect) continue;
    const glm::vec3 outside = unproject(camera, x, y, depth(rng));
    EXPECT_TRUE(sphereOutside(planes, outside, 0.0f)) << x << "," << y;
  }
  // Beyond near / far.
  EXPECT_TRUE(sphereOutside(planes, unproject(camera, 230, 120, 0.3f), 0.0f));
  EXPECT_TRUE(sphereOutside(planes, unproject(camera, 230, 120, 25.0f), 0.0f));
}

TEST(Camera, SphereStraddlingTheBorderIsKept) {
  const Camera camera = testCamera();
  const TileRect rect = makeTileRect(200, 100, 64, 48);
  const FrustumPlanes planes = tilePlanes(camera, rect);
  const float depth = 5.0f;
  const float pixel = 1.0f / pixelsPerUnit(camera, depth);  // world size of a pixel there
  // Centre 3 px left of the tile, radius 4 px: it reaches into the tile.
  const glm::vec3 c = unproject(camera, 197.0f, 120.0f, depth);
  EXPECT_FALSE(sphereOutside(planes, c, 4.0f * pixel));
  EXPECT_TRUE(sphereOutside(planes, c, 2.0f * pixel));
  // A margin of a pixel widens the tile.
  const glm::vec3 c2 = unproject(camera, 199.5f, 120.0f, depth);
  EXPECT_TRUE(sphereOutside(planes, c2, 0.0f));
  EXPECT_FALSE(sphereOutside(tilePlanes(camera, rect, 1.0f), c2, 0.0f));
  // Box test agrees on a box around the straddling sphere.
  const glm::vec3 r(4.0f * pixel);
  EXPECT_FALSE(boxOutside(planes, c - r, c + r));
  EXPECT_TRUE(boxOutside(planes, c - r * 0.4f, c + r * 0.4f));
}

TEST(Camera, ProjectedSizeMatchesProjection) {
  const Camera camera = testCamera();
  const glm::vec3 p = unproject(camera, 300, 200, 6.0f);
  const glm::mat4 view = viewMatrix(camera);
  const glm::vec3 right(view[0][0], view[1][0], view[2][0]);  // camera x axis in world
  const float r = 0.05f;
  const float measured =
      projectToWindow(camera, p + right * r).x - projectToWindow(camera, p - right * r).x;
  EXPECT_NEAR(viewDepth(camera, p), 6.0f, 1e-4f);
  EXPECT_NEAR(2.0f * projectedRadiusPixels(camera, r, viewDepth(camera, p)), measured, 0.02f);
  EXPECT_NEAR(pixelsPerUnit(camera, 1.0f), 180.0f / std::tan(glm::radians(25.0f)), 1e-2f);
}

TEST(Camera, CameraForBoundsFramesTheBox) {
  const glm::vec3 lo(-2.0f, 1.0f, 0.0f), hi(4.0f, 3.0f, 1.5f);
  for (const float az : {0.0f, 45.0f, 200.0f}) {
    for (const float el : {-30.0f, 20.0f, 90.0f}) {
      const Camera camera = cameraForBounds(lo, hi, 320, 200, az, el, 1.0f);
      ASSERT_NO_THROW(validateCamera(camera));
      for (int i = 0; i < 8; ++i) {
        const glm::vec3 corner((i & 1) ? hi.x : lo.x, (i & 2) ? hi.y : lo.y, (i & 4) ? hi.z : lo.z);
        const glm::vec4 w = projectToWindow(camera, corner);
        EXPECT_GE(w.x, 0.0f);
        EXPECT_LE(w.x, 320.0f);
        EXPECT_GE(w.y, 0.0f);
        EXPECT_LE(w.y, 200.0f);
        EXPECT_GT(w.z, 0.0f);
        EXPECT_LT(w.z, 1.0f);
      }
    }
  }
  // Azimuth 0, elevation 0, z up: eye on the +x side of the centre.
  const Camera side = cameraForBounds(lo, hi, 100, 100, 0.0f, 0.0f);
  EXPECT_GT(side.eye().x(), hi.x);
  EXPECT_NEAR(side.eye().y(), 2.0f, 1e-4f);
  // y up: azimuth 0 puts the eye on the +z side.
  const Camera yUp = cameraForBounds(lo, hi, 100, 100, 0.0f, 0.0f, 1.0f, 45.0f, {0, 1, 0});
  EXPECT_GT(yUp.eye().z(), hi.z);
  // Zoomed in: the eye is inside the sphere and near stays positive.
  const Camera inside = cameraForBounds(lo, hi, 100, 100, 10.0f, 10.0f, 0.1f);
  EXPECT_NO_THROW(validateCamera(inside));
}

TEST(Camera, ValidationRejectsBadCameras) {
  EXPECT_NO_THROW(validateCamera(testCamera()));
  Camera c = testCamera();
  c.set_image_width(0);
  EXPECT_THROW(validateCamera(c), UsageError);
  c = testCamera();
  c.set_near_plane(0.0f);
  EXPECT_THROW(validateCamera(c), UsageError);
  c = testCamera();
  c.set_far_plane(0.4f);
  EXPECT_THROW(validateCamera(c), UsageError);
  c = testCamera();
  c.set_fov_y_degrees(180.0f);
  EXPECT_THROW(validateCamera(c), UsageError);
  c = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 0, 1}, 45, 0.1f, 10, 10, 10);
  EXPECT_THROW(validateCamera(c), UsageError);  // up parallel to the view direction
  c = makeCamera({1, 1, 1}, {1, 1, 1}, {0, 0, 1}, 45, 0.1f, 10, 10, 10);
  EXPECT_THROW(validateCamera(c), UsageError);
  c = testCamera();
  c.mutable_eye()->set_x(std::nanf(""));
  EXPECT_THROW(validateCamera(c), UsageError);
}

TEST(Camera, TileInsideFrame) {
  const Camera camera = testCamera();
  EXPECT_TRUE(tileInsideFrame(camera, makeTileRect(0, 0, 640, 360)));
  EXPECT_TRUE(tileInsideFrame(camera, makeTileRect(600, 300, 40, 60)));
  EXPECT_FALSE(tileInsideFrame(camera, makeTileRect(601, 300, 40, 60)));
  EXPECT_FALSE(tileInsideFrame(camera, makeTileRect(0, 0, 0, 10)));
  EXPECT_FALSE(tileInsideFrame(camera, makeTileRect(0xffffffffu, 0, 2, 2)));
}

}  // namespace
}  // namespace pointillist
