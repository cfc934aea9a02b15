#pragma once
// RAII OSMesa context (Mesa llvmpipe) rendering into a caller-visible RGBA8
// buffer. OSMesa renders straight into that buffer, rows bottom-up
// (OSMESA_Y_UP), so after glFinish() pixels() is the image: no glReadPixels.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "common/image.hpp"

struct osmesa_context;

namespace pointillist::render {

// Compatibility: legacy (non-sprite) GL_POINTS, the fast points path on
// llvmpipe. Core: 3.3 core profile, where every point is a point sprite
// (~1.6x slower on llvmpipe). Both run the splat geometry shader.
enum class GlProfile { Compatibility, Core };
const char* profileName(GlProfile profile);
// "compat" / "compatibility" / "core"; throws UsageError otherwise.
GlProfile parseProfile(const std::string& name);

class OffscreenContext {
 public:
  // Creates a GL 3.3+ context of the profile and makes it current on this
  // thread. Throws RenderError when OSMesa cannot create it.
  explicit OffscreenContext(std::uint32_t width = 1, std::uint32_t height = 1,
                            GlProfile profile = GlProfile::Compatibility);
  ~OffscreenContext();
  OffscreenContext(const OffscreenContext&) = delete;
  OffscreenContext& operator=(const OffscreenContext&) = delete;

  // Sets the framebuffer size (memory only grows) and makes the context current.
  void resize(std::uint32_t width, std::uint32_t height);
  // Makes this context current on the calling thread (one thread at a time).
  void makeCurrent();

  std::uint32_t width() const { return width_; }
  std::uint32_t height() const { return height_; }
  GlProfile profile() const { return profile_; }
  int glVersion() const { return glVersion_; }  // major * 10 + minor, e.g. 45
  std::string versionString() const;            // GL_VERSION
  std::string rendererString() const;           // GL_RENDERER

  // The colour buffer: width*height RGBA8, rows bottom-up. Valid after
  // glFinish() (SplatRenderer::render does it) until the next draw or resize.
  std::span<const std::uint8_t> pixels() const;
  Image image() const { return Image(width_, height_, pixels()); }

 private:
  osmesa_context* context_ = nullptr;
  std::vector<std::uint8_t> buffer_;
  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  GlProfile profile_;
  int glVersion_ = 0;
};

// Throws RenderError("<what>: GL error 0x...") when glGetError reports any.
void throwOnGlError(const char* what);

}  // namespace pointillist::render
