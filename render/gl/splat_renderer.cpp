#include "render/gl/splat_renderer.hpp"

#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/glext.h>
#include <GL/osmesa.h>

#include <algorithm>
#include <chrono>
#include <climits>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <vector>

#include <glm/gtc/type_ptr.hpp>

#include "common/errors.hpp"

namespace pointillist::render {

namespace {

// Attribute locations shared by both programs (Splat layout: position 0,
// normal 12, radius 24, color 28).
constexpr GLuint kPosition = 0;
constexpr GLuint kColor = 1;
constexpr GLuint kRadius = 2;
constexpr GLuint kNormal = 3;

// Points: the centre is snapped in full-frame pixels (odd sizes to the pixel
// centre, even sizes to the pixel corner) and emitted with w = 1, so which
// pixels a point covers does not depend on floating-point rounding of the
// (tile-shifted) viewport transform: tiles match the full frame exactly.
constexpr const char* kPointsVertex = R"(#version 330 core
layout(location = 0) in vec3 inPosition;
layout(location = 1) in vec4 inColor;
layout(location = 2) in float inRadius;
uniform mat4 viewProjection;
uniform vec2 frameSize;
uniform float guard;          // pixels of clip volume beyond each frame edge
uniform float diameterScale;  // 2 * focal length in pixels * sizeScale
uniform float constantSize;   // > 0: fixed size
uniform float maxSize;
flat out vec4 vColor;
void main() {
  vec4 clip = viewProjection * vec4(inPosition, 1.0);
  vColor = inColor;
  float size = constantSize > 0.0 ? constantSize : inRadius * diameterScale / clip.w;
  size = clamp(floor(size + 0.5), 1.0, maxSize);
  gl_PointSize = size;
  if (clip.w <= 0.0) {
    gl_Position = vec4(0.0, 0.0, 2.0, 1.0);  // behind the eye: clipped
    return;
  }
  vec3 ndc = clip.xyz / clip.w;
  vec2 window = (ndc.xy * 0.5 + 0.5) * frameSize;
  vec2 snapped = mod(size, 2.0) == 1.0 ? floor(window) + 0.5 : floor(window + 0.5);
  gl_Position = vec4((snapped + guard) / (frameSize + 2.0 * guard) * 2.0 - 1.0, ndc.z, 1.0);
}
)";

constexpr const char* kPointsFragment = R"(#version 330 core
flat in vec4 vColor;
out vec4 fragColor;
void main() { fragColor = vColor; }
)";

constexpr const char* kSplatsVertex = R"(#version 330 core
layout(location = 0) in vec3 inPosition;
layout(location = 1) in vec4 inColor;
layout(location = 2) in float inRadius;
layout(location = 3) in vec3 inNormal;
out Splat {
  vec3 position;
  vec3 normal;
  float radius;
  vec4 color;
} vSplat;
void main() {
  vSplat.position = inPosition;
  vSplat.normal = inNormal;
  vSplat.radius = inRadius;
  vSplat.color = inColor;
}
)";

// Seed 002's transfer function: one vertex in, the disk's screen-space bounding
// rectangle out. Everything the fragment shader needs is flat, so each pixel's
// result depends only on its full-frame coordinates and this splat.
constexpr const char* kSplatsGeometry = R"(#version 330 core
layout(points) in;
layout(triangle_strip, max_vertices = 4) out;
in Splat {
  vec3 position;
  vec3 normal;
  float radius;
  vec4 color;
} vSplat[];
uniform mat4 view;
uniform mat4 projection;
uniform vec2 frameSize;
uniform float guard;        // pixels of clip volume beyond each frame edge
uniform float focalPixels;  // pixels per world unit at eye distance 1
uniform float radiusScale;
uniform float minPixelRadius;
uniform float nearPlane;
uniform int lighting;
uniform float ambient;
flat out vec3 gCentre;  // eye space
flat out vec3 gNormal;  // eye space, unit
flat out float gRadius2;
flat out vec4 gColor;

void emitClip(vec4 clip) {
  gl_Position = clip;
  EmitVertex();
}

// Frame clip coordinates -> the guarded viewport's.
vec4 guarded(vec4 clip) {
  return vec4(clip.xy * frameSize / (frameSize + 2.0 * guard), clip.zw);
}

void main() {
  vec3 centre = (view * vec4(vSplat[0].position, 1.0)).xyz;
  float dist = -centre.z;
  float radius = vSplat[0].radius * radiusScale;
  if (dist + radius < nearPlane) return;  // wholly nearer than the near plane
  radius = max(radius, minPixelRadius * max(dist, nearPlane) / focalPixels);
  vec3 n = mat3(view) * vSplat[0].normal;
  // No normal: a disk facing the eye.
  n = dot(n, n) > 0.25 ? normalize(n) : (dist > 0.0 ? -normalize(centre) : vec3(0.0, 0.0, 1.0));
  vec3 a = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
  vec3 u = normalize(cross(n, a));
  vec3 v = cross(n, u);

  float shade = 1.0;
  if (lighting != 0) {
    vec3 toEye = dist > 0.0 ? -normalize(centre) : vec3(0.0, 0.0, 1.0);
    shade = ambient + (1.0 - ambient) * abs(dot(n, toEye));
  }
  gCentre = centre;
  gNormal = n;
  gRadius2 = radius * radius;
  gColor = vec4(vSplat[0].color.rgb * shade, vSplat[0].color.a);

  vec4 corners[4];
  corners[0] = projection * vec4(centre + radius * (-u - v), 1.0);
  corners[1] = projection * vec4(centre + radius * (u - v), 1.0);
  corners[2] = projection * vec4(centre + radius * (-u + v), 1.0);
  corners[3] = projection * vec4(centre + radius * (u + v), 1.0);
  float minW = min(min(corners[0].w, corners[1].w), min(corners[2].w, corners[3].w));
  if (minW > 0.5 * nearPlane) {
    // The projected square contains the projected disk; its bounding box grown
    // by a pixel keeps every covered pixel centre well inside the rectangle.
    vec2 lo = vec2(1e30), hi = vec2(-1e30);
    for (int i = 0; i < 4; ++i) {
      vec2 window = (corners[i].xy / corners[i].w * 0.5 + 0.5) * frameSize;
      lo = min(lo, window);
      hi = max(hi, window);
    }
    lo = (lo - 1.0 + guard) / (frameSize + 2.0 * guard) * 2.0 - 1.0;
    hi = (hi + 1.0 + guard) / (frameSize + 2.0 * guard) * 2.0 - 1.0;
    // z = 0: depth clipping is done per pixel by the fragment shader.
    emitClip(vec4(lo.x, lo.y, 0.0, 1.0));
    emitClip(vec4(hi.x, lo.y, 0.0, 1.0));
    emitClip(vec4(lo.x, hi.y, 0.0, 1.0));
    emitClip(vec4(hi.x, hi.y, 0.0, 1.0));
  } else {
    // Crosses the eye plane: a slightly larger square in clip space, clipped by GL.
    float grow = 1.1;
    emitClip(guarded(projection * vec4(centre + grow * radius * (-u - v), 1.0)));
    emitClip(guarded(projection * vec4(centre + grow * radius * (u - v), 1.0)));
    emitClip(guarded(projection * vec4(centre + grow * radius * (-u + v), 1.0)));
    emitClip(guarded(projection * vec4(centre + grow * radius * (u + v), 1.0)));
  }
  EndPrimitive();
}
)";

constexpr const char* kSplatsFragment = R"(#version 330 core
flat in vec3 gCentre;
flat in vec3 gNormal;
flat in float gRadius2;
flat in vec4 gColor;
uniform vec2 frameSize;
uniform vec2 tileOrigin;   // full-frame pixel of the tile's bottom-left
uniform vec2 projScale;    // projection[0][0], projection[1][1]
uniform vec2 depthCoeff;   // projection[2][2], projection[3][2]
uniform uint drawSerial;   // changes every draw; see setUniforms
uniform int pass;          // 0 opaque, 1 blended visibility, 2 blended accumulation
uniform float depthOffsetRadii;
out vec4 fragColor;
void main() {
  if (drawSerial == 0xffffffffu) discard;
  // Exact full-frame pixel centre: integers + 0.5 are exact in float.
  vec2 ndc = (gl_FragCoord.xy + tileOrigin) / frameSize * 2.0 - 1.0;
  vec3 dir = vec3(ndc / projScale, -1.0);  // eye-space ray, z = -1
  float t = dot(gCentre, gNormal) / dot(dir, gNormal);
  vec3 hit = dir * t;
  vec3 d = hit - gCentre;
  float q = dot(d, d) / gRadius2;  // squared distance from the centre in radii
  if (!(t > 0.0) || !(q <= 1.0)) discard;
  // Visibility pass: pushed back so splats of the same surface blend.
  float z = pass == 1 ? hit.z - depthOffsetRadii * sqrt(gRadius2) : hit.z;
  float depth = (depthCoeff.x * z + depthCoeff.y) / (-z) * 0.5 + 0.5;
  if (!(depth >= 0.0 && depth <= 1.0)) discard;
  gl_FragDepth = depth;
  if (pass == 2) {
    float w = exp(-2.0 * q);  // Gaussian reconstruction kernel, cut at the radius
    fragColor = vec4(gColor.rgb * w, w);
  } else {
    fragColor = gColor;
  }
}
)";

// Blended mode, last pass: accumulated (sum w * colour, sum w) -> colour.
// Texture coordinates come from a varying, not gl_FragCoord (see setUniforms).
constexpr const char* kResolveVertex = R"(#version 330 core
out vec2 uv;
void main() {
  vec2 corner = vec2(float((gl_VertexID & 1) * 2), float((gl_VertexID & 2)));
  uv = corner;
  gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}
)";

constexpr const char* kResolveFragment = R"(#version 330 core
in vec2 uv;
uniform sampler2D accumulation;
uniform vec4 clearColor;
out vec4 fragColor;
void main() {
  vec4 sum = texture(accumulation, uv);
  fragColor = sum.a > 0.0 ? vec4(sum.rgb / sum.a, 1.0) : clearColor;
}
)";

GLuint compileShader(GLenum type, const char* source, const char* name) {
  const GLuint shader = glCreateShader(type);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = GL_FALSE;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (ok != GL_TRUE) {
    std::string log(4096, '\0');
    GLsizei length = 0;
    glGetShaderInfoLog(shader, static_cast<GLsizei>(log.size()), &length, log.data());
    log.resize(static_cast<std::size_t>(length));
    glDeleteShader(shader);
    throw RenderError(std::string("compiling ") + name + ": " + log);
  }
  return shader;
}

GLuint linkProgram(const char* vertex, const char* geometry, const char* fragment,
                   const char* name) {
  std::vector<GLuint> shaders;
  shaders.push_back(compileShader(GL_VERTEX_SHADER, vertex, name));
  if (geometry != nullptr) shaders.push_back(compileShader(GL_GEOMETRY_SHADER, geometry, name));
  shaders.push_back(compileShader(GL_FRAGMENT_SHADER, fragment, name));
  const GLuint program = glCreateProgram();
  for (GLuint shader : shaders) glAttachShader(program, shader);
  glLinkProgram(program);
  for (GLuint shader : shaders) glDeleteShader(shader);
  GLint ok = GL_FALSE;
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (ok != GL_TRUE) {
    std::string log(4096, '\0');
    GLsizei length = 0;
    glGetProgramInfoLog(program, static_cast<GLsizei>(log.size()), &length, log.data());
    log.resize(static_cast<std::size_t>(length));
    glDeleteProgram(program);
    throw RenderError(std::string("linking ") + name + ": " + log);
  }
  return program;
}

// Clip volume beyond each frame edge, in pixels: GL clips points by their
// centre, so without it a wide point (or, for splats, nothing) whose centre
// is just outside the frame would vanish although part of it is inside.
// Half the largest point size llvmpipe draws (255).
constexpr std::int64_t kGuardPixels = 128;

const void* byteOffset(std::size_t offset) {
  return reinterpret_cast<const void*>(offset);
}

GLint uniform(GLuint program, const char* name) {
  return glGetUniformLocation(program, name);
}

}  // namespace

struct SplatRenderer::Programs {
  GLuint points = 0;
  GLuint splats = 0;   // also the blended mode's two passes
  GLuint resolve = 0;  // blended mode's normalization
};

const char* splatModeName(SplatMode mode) {
  switch (mode) {
    case SplatMode::Splats:
      return "splats";
    case SplatMode::Blended:
      return "blended";
    case SplatMode::Points:
      break;
  }
  return "points";
}

SplatMode parseSplatMode(const std::string& name) {
  if (name == "points") return SplatMode::Points;
  if (name == "splats") return SplatMode::Splats;
  if (name == "blended") return SplatMode::Blended;
  throw UsageError("unknown render mode '" + name + "' (points, splats or blended)");
}

SplatMode splatModeFromProto(v1::RenderMode mode) {
  switch (mode) {
    case v1::RENDER_MODE_POINTS:
      return SplatMode::Points;
    case v1::RENDER_MODE_SPLATS:
      return SplatMode::Splats;
    default:
      throw UsageError("render mode " + v1::RenderMode_Name(mode) +
                       " is not drawn by SplatRenderer");
  }
}

SplatRenderer::SplatRenderer(OffscreenContext& context)
    : context_(context), programs_(std::make_unique<Programs>()) {
  context_.makeCurrent();
  glGenVertexArrays(1, &vertexArray_);
  GLfloat range[2] = {1.0f, 1.0f};
  glGetFloatv(GL_ALIASED_POINT_SIZE_RANGE, range);
  maxPointSizeGl_ = range[1];
  GLint dims[2] = {0, 0};
  glGetIntegerv(GL_MAX_VIEWPORT_DIMS, dims);
  maxViewport_ = std::min(dims[0], dims[1]);
  GLint bounds[2] = {0, 0};
  glGetIntegerv(GL_VIEWPORT_BOUNDS_RANGE, bounds);
  viewportBoundsMin_ = bounds[0];
  throwOnGlError("SplatRenderer");
}

SplatRenderer::~SplatRenderer() {
  try {
    context_.makeCurrent();  // another context may be current
  } catch (const std::exception&) {
    return;  // cannot reach our objects; they die with the context
  }
  releaseAll();
  destroy(scratch_);
  destroyAccumulation();
  for (GLuint prog : {programs_->points, programs_->splats, programs_->resolve}) {
    if (prog != 0) glDeleteProgram(prog);
  }
  glDeleteVertexArrays(1, &vertexArray_);
}

void SplatRenderer::upload(Cell& cell, std::span<const Splat> splats) {
  if (splats.size() > static_cast<std::size_t>(INT_MAX)) {
    throw UsageError("uploadCell: more than 2^31 splats in one cell");
  }
  if (cell.buffer == 0) glGenBuffers(1, &cell.buffer);
  glBindBuffer(GL_ARRAY_BUFFER, cell.buffer);
  // llvmpipe keeps buffers in ordinary memory: this is one memcpy.
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(splats.size_bytes()),
               splats.empty() ? nullptr : splats.data(), GL_STATIC_DRAW);
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  cell.count = static_cast<std::uint32_t>(splats.size());
  throwOnGlError("uploadCell");
}

void SplatRenderer::destroy(Cell& cell) {
  if (cell.buffer != 0) glDeleteBuffers(1, &cell.buffer);
  cell = Cell{};
}

void SplatRenderer::uploadCell(std::uint32_t id, std::span<const Splat> splats) {
  context_.makeCurrent();
  Cell& cell = cells_[id];
  uploadedBytes_ -= std::uint64_t{cell.count} * sizeof(Splat);
  cell.count = 0;
  try {
    upload(cell, splats);
  } catch (...) {
    destroy(cell);
    cells_.erase(id);
    throw;
  }
  uploadedBytes_ += splats.size_bytes();
}

void SplatRenderer::releaseCell(std::uint32_t id) {
  const auto it = cells_.find(id);
  if (it == cells_.end()) return;
  context_.makeCurrent();
  uploadedBytes_ -= std::uint64_t{it->second.count} * sizeof(Splat);
  destroy(it->second);
  cells_.erase(it);
}

void SplatRenderer::releaseAll() {
  if (cells_.empty()) return;
  context_.makeCurrent();
  for (auto& entry : cells_) destroy(entry.second);
  cells_.clear();
  uploadedBytes_ = 0;
}

std::uint32_t SplatRenderer::cellSplatCount(std::uint32_t id) const {
  const auto it = cells_.find(id);
  return it == cells_.end() ? 0 : it->second.count;
}

std::uint32_t SplatRenderer::guardPixels(const Camera& camera) const {
  const auto largest =
      static_cast<std::int64_t>(std::max(camera.image_width(), camera.image_height()));
  const std::int64_t byDims = (maxViewport_ - largest) / 2;
  const std::int64_t byBounds =
      -viewportBoundsMin_ -
      static_cast<std::int64_t>(std::max(camera.image_width(), camera.image_height()));
  return static_cast<std::uint32_t>(
      std::clamp<std::int64_t>(std::min(byDims, byBounds), 0, kGuardPixels));
}

unsigned SplatRenderer::program(SplatMode mode) {
  if (mode == SplatMode::Points) {
    if (programs_->points == 0) {
      programs_->points = linkProgram(kPointsVertex, nullptr, kPointsFragment, "points program");
    }
    return programs_->points;
  }
  if (programs_->splats == 0) {
    programs_->splats =
        linkProgram(kSplatsVertex, kSplatsGeometry, kSplatsFragment, "splats program");
  }
  return programs_->splats;
}

void SplatRenderer::setUniforms(unsigned prog, const Camera& camera, const TileRect& rect,
                                const RenderSettings& settings) {
  const glm::mat4 view = viewMatrix(camera);
  const glm::mat4 projection = projectionMatrix(camera);
  const glm::mat4 viewProjection = viewProjectionMatrix(camera);
  const float focal = pixelsPerUnit(camera, 1.0f);
  const float scale = settings.sizeScale > 0.0f ? settings.sizeScale : 1.0f;
  const auto frameW = static_cast<float>(camera.image_width());
  const auto frameH = static_cast<float>(camera.image_height());
  glUniform2f(uniform(prog, "frameSize"), frameW, frameH);
  glUniform1f(uniform(prog, "guard"), static_cast<float>(guardPixels(camera)));
  if (settings.mode == SplatMode::Points) {
    glUniformMatrix4fv(uniform(prog, "viewProjection"), 1, GL_FALSE,
                       glm::value_ptr(viewProjection));
    glUniform1f(uniform(prog, "diameterScale"), 2.0f * focal * scale);
    glUniform1f(uniform(prog, "constantSize"), std::max(settings.pointSize, 0.0f));
    glUniform1f(uniform(prog, "maxSize"),
                std::clamp(std::floor(settings.maxPointSize), 1.0f, maxPointSizeGl_));
    return;
  }
  glUniformMatrix4fv(uniform(prog, "view"), 1, GL_FALSE, glm::value_ptr(view));
  glUniformMatrix4fv(uniform(prog, "projection"), 1, GL_FALSE, glm::value_ptr(projection));
  glUniform1f(uniform(prog, "focalPixels"), focal);
  glUniform1f(uniform(prog, "radiusScale"), scale);
  glUniform1f(uniform(prog, "minPixelRadius"), std::max(settings.minPixelRadius, 0.0f));
  glUniform1f(uniform(prog, "nearPlane"), camera.near_plane());
  glUniform1i(uniform(prog, "lighting"), settings.lighting ? 1 : 0);
  glUniform1f(uniform(prog, "ambient"), std::clamp(settings.ambient, 0.0f, 1.0f));
  glUniform2f(uniform(prog, "tileOrigin"), static_cast<float>(rect.x()),
              static_cast<float>(rect.y()));
  glUniform2f(uniform(prog, "projScale"), projection[0][0], projection[1][1]);
  glUniform2f(uniform(prog, "depthCoeff"), projection[2][2], projection[3][2]);
  // Mesa 22.3 OSMesa: after OSMesaMakeCurrent changes the buffer height, the
  // y flip behind gl_FragCoord keeps the old height until a fragment-shader
  // constant changes (glUniform with an unchanged value uploads nothing), so a
  // tile drawn with the same uniforms as the previous, taller one sees
  // gl_FragCoord.y off by the height difference. A value that changes on
  // every draw forces the re-evaluation.
  drawSerial_ = drawSerial_ == 0xfffffffeu ? 0u : drawSerial_ + 1u;
  glUniform1ui(uniform(prog, "drawSerial"), drawSerial_);
  glUniform1i(uniform(prog, "pass"), 0);
  glUniform1f(uniform(prog, "depthOffsetRadii"), std::max(settings.blendDepthRadii, 0.0f));
}

void SplatRenderer::ensureAccumulation(std::uint32_t width, std::uint32_t height) {
  if (accumulation_.framebuffer == 0) {
    glGenFramebuffers(1, &accumulation_.framebuffer);
    glGenTextures(1, &accumulation_.color);
    glGenRenderbuffers(1, &accumulation_.depth);
  }
  if (accumulation_.width == width && accumulation_.height == height) return;
  glBindTexture(GL_TEXTURE_2D, accumulation_.color);
  // Float sums of w * colour and w; 8 bits would band after a few splats.
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA32F, static_cast<GLsizei>(width),
               static_cast<GLsizei>(height), 0, GL_RGBA, GL_FLOAT, nullptr);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glBindTexture(GL_TEXTURE_2D, 0);
  glBindRenderbuffer(GL_RENDERBUFFER, accumulation_.depth);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, static_cast<GLsizei>(width),
                        static_cast<GLsizei>(height));
  glBindRenderbuffer(GL_RENDERBUFFER, 0);
  glBindFramebuffer(GL_FRAMEBUFFER, accumulation_.framebuffer);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, accumulation_.color,
                         0);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER,
                            accumulation_.depth);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  if (status != GL_FRAMEBUFFER_COMPLETE) {
    throw RenderError("blended mode: accumulation framebuffer incomplete (status " +
                      std::to_string(status) + ")");
  }
  accumulation_.width = width;
  accumulation_.height = height;
}

void SplatRenderer::destroyAccumulation() {
  if (accumulation_.framebuffer == 0) return;
  glDeleteFramebuffers(1, &accumulation_.framebuffer);
  glDeleteTextures(1, &accumulation_.color);
  glDeleteRenderbuffers(1, &accumulation_.depth);
  accumulation_ = Accumulation{};
}

RenderStats SplatRenderer::draw(
    const Camera& camera, const TileRect& rect,
    std::span<const std::pair<const Cell*, std::span<const DrawRange>>> groups,
    const RenderSettings& settings) {
  const auto start = std::chrono::steady_clock::now();
  context_.resize(rect.width(), rect.height());
  const bool points = settings.mode == SplatMode::Points;
  const bool blended = settings.mode == SplatMode::Blended;
  if (blended) {
    ensureAccumulation(rect.width(), rect.height());
    glBindFramebuffer(GL_FRAMEBUFFER, accumulation_.framebuffer);
  }
  // The full frame's viewport grown by the guard band, shifted so the tile's
  // pixels land in the buffer.
  const auto guard = static_cast<GLint>(guardPixels(camera));
  glViewport(-static_cast<GLint>(rect.x()) - guard, -static_cast<GLint>(rect.y()) - guard,
             static_cast<GLsizei>(camera.image_width()) + 2 * guard,
             static_cast<GLsizei>(camera.image_height()) + 2 * guard);
  glDisable(GL_SCISSOR_TEST);
  glDisable(GL_BLEND);
  glDisable(GL_CULL_FACE);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_TRUE);
  glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
  if (blended) {
    glClearColor(0.0f, 0.0f, 0.0f, 0.0f);
  } else {
    glClearColor(settings.clearColor[0], settings.clearColor[1], settings.clearColor[2],
                 settings.clearColor[3]);
  }
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);

  const GLuint prog = program(settings.mode);
  glUseProgram(prog);
  setUniforms(prog, camera, rect, settings);
  if (points) {
    glEnable(GL_PROGRAM_POINT_SIZE);
    if (context_.profile() == GlProfile::Compatibility) glDisable(GL_POINT_SPRITE);
  }

  glBindVertexArray(vertexArray_);
  glEnableVertexAttribArray(kPosition);
  glEnableVertexAttribArray(kColor);
  glEnableVertexAttribArray(kRadius);
  if (points) {
    glDisableVertexAttribArray(kNormal);
  } else {
    glEnableVertexAttribArray(kNormal);
  }

  RenderStats stats;
  std::vector<GLint> firsts;
  std::vector<GLsizei> counts;
  auto drawAll = [&] {
    for (const auto& [cell, ranges] : groups) {
      firsts.clear();
      counts.clear();
      for (const DrawRange& range : ranges) {
        if (range.count == 0) continue;
        firsts.push_back(static_cast<GLint>(range.offset));
        counts.push_back(static_cast<GLsizei>(range.count));
      }
      if (firsts.empty()) continue;
      glBindBuffer(GL_ARRAY_BUFFER, cell->buffer);
      constexpr GLsizei stride = sizeof(Splat);
      glVertexAttribPointer(kPosition, 3, GL_FLOAT, GL_FALSE, stride,
                            byteOffset(offsetof(Splat, position)));
      glVertexAttribPointer(kColor, 4, GL_UNSIGNED_BYTE, GL_TRUE, stride,
                            byteOffset(offsetof(Splat, color)));
      glVertexAttribPointer(kRadius, 1, GL_FLOAT, GL_FALSE, stride,
                            byteOffset(offsetof(Splat, radius)));
      if (!points) {
        glVertexAttribPointer(kNormal, 3, GL_FLOAT, GL_FALSE, stride,
                              byteOffset(offsetof(Splat, normal)));
      }
      glMultiDrawArrays(GL_POINTS, firsts.data(), counts.data(),
                        static_cast<GLsizei>(firsts.size()));
      ++stats.drawCalls;
    }
  };
  for (const auto& group : groups) {
    for (const DrawRange& range : group.second) stats.splats += range.count;
  }

  if (!blended) {
    drawAll();
  } else {
    // Seed 002 splats, blended (EWA-style, two passes): (1) depth only, pushed
    // back by depthOffsetRadii radii; (2) additive w * colour and w of every
    // splat within that offset of the visible surface; (3) resolve below.
    const GLint passLocation = uniform(prog, "pass");
    glUniform1i(passLocation, 1);
    glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    drawAll();
    glUniform1i(passLocation, 2);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glDepthMask(GL_FALSE);
    glDepthFunc(GL_LEQUAL);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE);
    drawAll();
    glDisable(GL_BLEND);
    glDepthMask(GL_TRUE);
    glDepthFunc(GL_LESS);

    // (3) normalize the sums into the context's buffer.
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    glViewport(0, 0, static_cast<GLsizei>(rect.width()), static_cast<GLsizei>(rect.height()));
    glDisable(GL_DEPTH_TEST);
    for (GLuint attribute : {kPosition, kColor, kRadius, kNormal}) {
      glDisableVertexAttribArray(attribute);
    }
    if (programs_->resolve == 0) {
      programs_->resolve =
          linkProgram(kResolveVertex, nullptr, kResolveFragment, "blend resolve program");
    }
    glUseProgram(programs_->resolve);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, accumulation_.color);
    glUniform1i(uniform(programs_->resolve, "accumulation"), 0);
    glUniform4f(uniform(programs_->resolve, "clearColor"), settings.clearColor[0],
                settings.clearColor[1], settings.clearColor[2], settings.clearColor[3]);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindTexture(GL_TEXTURE_2D, 0);
    glEnable(GL_DEPTH_TEST);
  }
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  glBindVertexArray(0);
  glUseProgram(0);
  // The image is in the context's buffer once the rasterizer threads are done.
  glFinish();
  throwOnGlError("SplatRenderer::render");
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

RenderStats SplatRenderer::render(const Camera& camera, const TileRect& rect,
                                  std::span<const DrawRange> ranges,
                                  const RenderSettings& settings) {
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("SplatRenderer::render: tile rectangle is empty or outside the image");
  }
  // Canonical order (cell, offset): equal-depth ties resolve the same way in a
  // tile as in the full frame.
  std::vector<DrawRange> sorted(ranges.begin(), ranges.end());
  std::sort(sorted.begin(), sorted.end(), [](const DrawRange& a, const DrawRange& b) {
    return a.cell != b.cell ? a.cell < b.cell : a.offset < b.offset;
  });
  std::vector<std::pair<const Cell*, std::span<const DrawRange>>> groups;
  for (std::size_t i = 0; i < sorted.size();) {
    const auto it = cells_.find(sorted[i].cell);
    if (it == cells_.end()) {
      throw UsageError("SplatRenderer::render: cell " + std::to_string(sorted[i].cell) +
                       " is not uploaded");
    }
    std::size_t j = i;
    for (; j < sorted.size() && sorted[j].cell == sorted[i].cell; ++j) {
      if (std::uint64_t{sorted[j].offset} + sorted[j].count > it->second.count) {
        throw UsageError("SplatRenderer::render: range [" + std::to_string(sorted[j].offset) +
                         ", +" + std::to_string(sorted[j].count) + ") outside cell " +
                         std::to_string(sorted[j].cell) + " of " +
                         std::to_string(it->second.count) + " splats");
      }
    }
    groups.emplace_back(&it->second, std::span<const DrawRange>(sorted).subspan(i, j - i));
    i = j;
  }
  return draw(camera, rect, groups, settings);
}

RenderStats SplatRenderer::renderSplats(const Camera& camera, const TileRect& rect,
                                        std::span<const Splat> splats,
                                        const RenderSettings& settings) {
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("SplatRenderer::renderSplats: tile rectangle is empty or outside the image");
  }
  context_.makeCurrent();
  upload(scratch_, splats);
  const DrawRange all{0, 0, scratch_.count};
  const std::pair<const Cell*, std::span<const DrawRange>> group{&scratch_, {&all, 1}};
  return draw(camera, rect, {&group, 1}, settings);
}

}  // namespace pointillist::render
