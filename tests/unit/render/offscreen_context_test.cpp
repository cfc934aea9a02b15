#include "render/gl/offscreen_context.hpp"

#include <gtest/gtest.h>

#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/osmesa.h>

#include <cstring>
#include <vector>

#include "common/errors.hpp"

namespace pointillist::render {
namespace {

TEST(OffscreenContext, CreatesBothProfiles) {
  for (const GlProfile profile : {GlProfile::Compatibility, GlProfile::Core}) {
    OffscreenContext context(16, 8, profile);
    EXPECT_GE(context.glVersion(), 33) << context.versionString();
    EXPECT_EQ(context.profile(), profile);
    const bool isCore = context.versionString().find("Core") != std::string::npos;
    EXPECT_EQ(isCore, profile == GlProfile::Core) << context.versionString();
  }
  EXPECT_EQ(parseProfile("core"), GlProfile::Core);
  EXPECT_EQ(parseProfile("compat"), GlProfile::Compatibility);
  EXPECT_THROW(parseProfile("es"), UsageError);
}

// OSMesa renders into our buffer directly, bottom row first: glReadPixels
// would return the same bytes.
TEST(OffscreenContext, BufferIsTheImageBottomUp) {
  OffscreenContext context(7, 5);
  glClearColor(0.0f, 0.0f, 1.0f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  glEnable(GL_SCISSOR_TEST);
  glScissor(0, 0, 7, 1);  // bottom row red
  glClearColor(1.0f, 0.0f, 0.0f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  glDisable(GL_SCISSOR_TEST);
  glFinish();
  const auto pixels = context.pixels();
  ASSERT_EQ(pixels.size(), 7u * 5u * 4u);
  EXPECT_EQ(pixels[0], 255);  // row 0 = bottom = red
  EXPECT_EQ(pixels[2], 0);
  EXPECT_EQ(pixels[4 * 7 * 4 + 2], 255);  // top row blue
  std::vector<std::uint8_t> read(pixels.size());
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, 7, 5, GL_RGBA, GL_UNSIGNED_BYTE, read.data());
  EXPECT_EQ(std::memcmp(read.data(), pixels.data(), read.size()), 0);
  const Image image = context.image();
  EXPECT_EQ(image.at(3, 0), (Rgba8{255, 0, 0, 255}));
  EXPECT_EQ(image.at(3, 4), (Rgba8{0, 0, 255, 255}));
}

TEST(OffscreenContext, ResizeKeepsWorking) {
  OffscreenContext context(4, 4);
  for (const auto& [w, h] : {std::pair{64u, 32u}, std::pair{3u, 9u}, std::pair{200u, 100u}}) {
    context.resize(w, h);
    glViewport(0, 0, static_cast<GLsizei>(w), static_cast<GLsizei>(h));
    glClearColor(0.0f, 1.0f, 0.0f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT);
    glFinish();
    const Image image = context.image();
    EXPECT_EQ(image.width(), w);
    EXPECT_EQ(image.at(w - 1, h - 1), (Rgba8{0, 255, 0, 255}));
    throwOnGlError("resize test");
  }
  EXPECT_THROW(context.resize(0, 4), RenderError);
}

TEST(OffscreenContext, GlErrorsBecomeRenderErrors) {
  OffscreenContext context(4, 4);
  glEnable(0x1234);  // GL_INVALID_ENUM
  EXPECT_THROW(throwOnGlError("bad enum"), RenderError);
  EXPECT_NO_THROW(throwOnGlError("cleared"));
}

}  // namespace
}  // namespace pointillist::render
