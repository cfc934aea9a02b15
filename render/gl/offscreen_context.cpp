#include "render/gl/offscreen_context.hpp"

#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/glext.h>
#include <GL/osmesa.h>

#include <cstdio>
#include <string>

#include "common/errors.hpp"

namespace pointillist::render {

namespace {

constexpr std::uint32_t kMaxSize = 16384;  // llvmpipe's largest framebuffer

std::string hex(unsigned value) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%04x", value);
  return text;
}

}  // namespace

const char* profileName(GlProfile profile) {
  return profile == GlProfile::Core ? "core" : "compat";
}

GlProfile parseProfile(const std::string& name) {
  if (name == "compat" || name == "compatibility") return GlProfile::Compatibility;
  if (name == "core") return GlProfile::Core;
  throw UsageError("unknown GL profile '" + name + "' (compat or core)");
}

OffscreenContext::OffscreenContext(std::uint32_t width, std::uint32_t height, GlProfile profile)
    : profile_(profile) {
  const int attributes[] = {
      OSMESA_FORMAT,
      OSMESA_RGBA,
      OSMESA_DEPTH_BITS,
      24,
      OSMESA_STENCIL_BITS,
      0,
      OSMESA_ACCUM_BITS,
      0,
      OSMESA_PROFILE,
      profile == GlProfile::Core ? OSMESA_CORE_PROFILE : OSMESA_COMPAT_PROFILE,
      OSMESA_CONTEXT_MAJOR_VERSION,
      3,
      OSMESA_CONTEXT_MINOR_VERSION,
      3,
      0};
  context_ = OSMesaCreateContextAttribs(attributes, nullptr);
  if (context_ == nullptr) {
    throw RenderError(std::string("OSMesaCreateContextAttribs failed for a GL 3.3 ") +
                      profileName(profile) + " context");
  }
  try {
    resize(width, height);
    GLint major = 0, minor = 0;
    glGetIntegerv(GL_MAJOR_VERSION, &major);
    glGetIntegerv(GL_MINOR_VERSION, &minor);
    glVersion_ = major * 10 + minor;
    if (glVersion_ < 33) throw RenderError("OSMesa gave GL " + versionString() + ", need 3.3");
    // Rows bottom-up in our buffer, the GL convention (also OSMesa's default).
    OSMesaPixelStore(OSMESA_Y_UP, 1);
    throwOnGlError("OffscreenContext");
  } catch (...) {
    OSMesaDestroyContext(context_);
    throw;
  }
}

OffscreenContext::~OffscreenContext() {
  if (OSMesaGetCurrentContext() == context_) OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
  OSMesaDestroyContext(context_);
}

void OffscreenContext::resize(std::uint32_t width, std::uint32_t height) {
  if (width == 0 || height == 0 || width > kMaxSize || height > kMaxSize) {
    throw RenderError("OffscreenContext: unsupported size " + std::to_string(width) + "x" +
                      std::to_string(height));
  }
  const std::size_t bytes = static_cast<std::size_t>(width) * height * 4;
  if (buffer_.size() < bytes) buffer_.resize(bytes);
  width_ = width;
  height_ = height;
  makeCurrent();
}

void OffscreenContext::makeCurrent() {
  if (!OSMesaMakeCurrent(context_, buffer_.data(), GL_UNSIGNED_BYTE, static_cast<GLsizei>(width_),
                         static_cast<GLsizei>(height_))) {
    throw RenderError("OSMesaMakeCurrent failed for " + std::to_string(width_) + "x" +
                      std::to_string(height_));
  }
}

std::string OffscreenContext::versionString() const {
  const GLubyte* text = glGetString(GL_VERSION);
  return text != nullptr ? reinterpret_cast<const char*>(text) : "?";
}

std::string OffscreenContext::rendererString() const {
  const GLubyte* text = glGetString(GL_RENDERER);
  return text != nullptr ? reinterpret_cast<const char*>(text) : "?";
}

std::span<const std::uint8_t> OffscreenContext::pixels() const {
  return {buffer_.data(), static_cast<std::size_t>(width_) * height_ * 4};
}

void throwOnGlError(const char* what) {
  GLenum error = glGetError();
  if (error == GL_NO_ERROR) return;
  std::string codes;
  for (int i = 0; error != GL_NO_ERROR && i < 8; ++i, error = glGetError()) {
    codes += (codes.empty() ? "" : ", ") + hex(error);
  }
  throw RenderError(std::string(what) + ": GL error " + codes);
}

}  // namespace pointillist::render
