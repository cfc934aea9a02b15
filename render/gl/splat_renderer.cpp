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
#include <cstring>
#include <exception>
#include <initializer_list>
#include <limits>
#include <string>
#include <vector>

#include <glm/gtc/type_ptr.hpp>

#include "common/errors.hpp"
#include "render/gl/embedded_shaders.hpp"

namespace pointillist::render {

namespace {

// Attribute locations shared by both programs (Splat layout: position 0,
// normal 12, radius 24, color 28).
constexpr GLuint kPosition = 0;
constexpr GLuint kColor = 1;
constexpr GLuint kRadius = 2;
constexpr GLuint kNormal = 3;

// The GLSL lives in render/gl/shaders/ and is compiled in (embedded_shaders.hpp):
//   points.vert/.frag  points: the centre is snapped in full-frame pixels (odd
//                      sizes to the pixel centre, even sizes to the pixel corner)
//                      and emitted with w = 1, so which pixels a point covers
//                      does not depend on floating-point rounding of the
//                      (tile-shifted) viewport transform: tiles match the full
//                      frame exactly.
//   splats.vert/.geom/.frag  seed 002's transfer function: one vertex in, the
//                      disk's screen-space bounding rectangle out. Everything
//                      the fragment shader needs is flat, so each pixel's result
//                      depends only on its full-frame coordinates and this splat.
//   resolve.vert/.frag blended mode, last pass: accumulated (sum w * colour,
//                      sum w) -> colour. Texture coordinates come from a
//                      varying, not gl_FragCoord (see setUniforms).

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

// Several vertex shaders may share a program: point_emit.vert holds the
// points' vertex work that points.vert and instanced_points.vert call.
GLuint linkProgram(std::initializer_list<const char*> vertex, const char* geometry,
                   const char* fragment, const char* name) {
  std::vector<GLuint> shaders;
  for (const char* source : vertex)
    shaders.push_back(compileShader(GL_VERTEX_SHADER, source, name));
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

// The bound buffer's splats from byte `base` on, as the points and splats
// programs read them.
void splatAttributes(std::size_t base) {
  constexpr GLsizei stride = sizeof(Splat);
  glVertexAttribPointer(kPosition, 3, GL_FLOAT, GL_FALSE, stride,
                        byteOffset(base + offsetof(Splat, position)));
  glVertexAttribPointer(kColor, 4, GL_UNSIGNED_BYTE, GL_TRUE, stride,
                        byteOffset(base + offsetof(Splat, color)));
  glVertexAttribPointer(kRadius, 1, GL_FLOAT, GL_FALSE, stride,
                        byteOffset(base + offsetof(Splat, radius)));
  glVertexAttribPointer(kNormal, 3, GL_FLOAT, GL_FALSE, stride,
                        byteOffset(base + offsetof(Splat, normal)));
}

// instanced_points.vert's per-instance translation.
constexpr GLuint kTag = 4;
constexpr GLuint kTranslation = 5;

// statistical_points.vert reads each node from a buffer texture of
// StatisticalInstance records (10 RGBA32F texels; llvmpipe spends about
// 0.75 us per instance of an instanced draw, and a cut holds about 100 k nodes
// of 3-13 points) and its samples from a buffer texture of GaussianSample
// records (2 texels), so a draw of n points per node over m nodes is one
// glDrawArrays of n * m vertices.
constexpr GLint kStatisticalNodeUnit = 2;
constexpr GLint kStatisticalSampleUnit = 3;
constexpr GLuint kStatisticalAttributes = 14;  // every attribute location the modes use
struct StatisticalInstance {
  float mean[4];     // w: point width in pixels
  float axes[3][4];  // axes[k] * sigma[k]; w: colour channel k
  float normal[3][4];
  float colorAxes[3][4];
};
static_assert(sizeof(StatisticalInstance) == 40 * sizeof(float));

StatisticalInstance statisticalInstance(const StatisticalNode& node, float pointPixels) {
  StatisticalInstance out{};
  for (int i = 0; i < 3; ++i) {
    out.mean[i] = node.mean[i];
    out.axes[i][3] = node.color[i];
    for (int k = 0; k < 3; ++k) {
      out.axes[k][i] = node.axes[k][i] * node.sigma[k];
      out.colorAxes[k][i] = node.colorAxes[k][i] * node.sigmaColor[k];
    }
    out.normal[0][i] = node.normalFrame[0][i] * node.sigmaNormal[0];
    out.normal[1][i] = node.normalFrame[1][i] * node.sigmaNormal[1];
    out.normal[2][i] = node.normalFrame[2][i];
  }
  out.mean[3] = pointPixels;
  return out;
}

}  // namespace

struct SplatRenderer::Programs {
  GLuint points = 0;
  GLuint splats = 0;       // also the blended mode's two passes
  GLuint resolve = 0;      // blended mode's normalization
  GLuint instanced = 0;    // instanced sections' pools (seed 000)
  GLuint statistical = 0;  // statistical nodes (seed 004)
};

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
  for (GLuint prog : {programs_->points, programs_->splats, programs_->resolve,
                      programs_->instanced, programs_->statistical}) {
    if (prog != 0) glDeleteProgram(prog);
  }
  for (GLuint buffer : {sampleBuffer_, instanceBuffer_}) {
    if (buffer != 0) glDeleteBuffers(1, &buffer);
  }
  for (GLuint texture : {nodeTexture_, sampleTexture_}) {
    if (texture != 0) glDeleteTextures(1, &texture);
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
  cell.capacity = cell.count;
  cell.sections.clear();
  cell.statistical.reset();
  throwOnGlError("uploadCell");
}

void SplatRenderer::destroy(Cell& cell) {
  if (cell.buffer != 0) glDeleteBuffers(1, &cell.buffer);
  cell = Cell{};
}

void SplatRenderer::uploadCell(std::uint32_t id, std::span<const Splat> splats) {
  context_.makeCurrent();
  Cell& cell = cells_[id];
  uploadedBytes_ -= std::uint64_t{cell.capacity} * sizeof(Splat);
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

void SplatRenderer::writeToCell(std::uint32_t id, std::uint32_t first,
                                std::span<const Splat> splats, std::size_t room) {
  if (splats.empty()) return;
  const std::uint64_t end = std::uint64_t{first} + splats.size();
  const std::uint64_t capacity = std::max<std::uint64_t>(end, room);
  if (capacity > static_cast<std::uint64_t>(INT_MAX)) {
    throw UsageError("writeToCell: more than 2^31 splats in one cell");
  }
  context_.makeCurrent();
  Cell& cell = cells_[id];
  if (cell.buffer == 0 || cell.capacity < end) {
    GLuint grown = 0;
    glGenBuffers(1, &grown);
    glBindBuffer(GL_COPY_WRITE_BUFFER, grown);
    glBufferData(GL_COPY_WRITE_BUFFER, static_cast<GLsizeiptr>(capacity * sizeof(Splat)), nullptr,
                 GL_STATIC_DRAW);
    if (cell.count > 0) {
      glBindBuffer(GL_COPY_READ_BUFFER, cell.buffer);
      glCopyBufferSubData(GL_COPY_READ_BUFFER, GL_COPY_WRITE_BUFFER, 0, 0,
                          static_cast<GLsizeiptr>(std::uint64_t{cell.count} * sizeof(Splat)));
      glBindBuffer(GL_COPY_READ_BUFFER, 0);
    }
    glBindBuffer(GL_COPY_WRITE_BUFFER, 0);
    try {
      throwOnGlError("writeToCell");
    } catch (...) {
      glDeleteBuffers(1, &grown);
      throw;
    }
    if (cell.buffer != 0) glDeleteBuffers(1, &cell.buffer);
    cell.buffer = grown;
    uploadedBytes_ += (capacity - cell.capacity) * sizeof(Splat);
    cell.capacity = static_cast<std::uint32_t>(capacity);
  }
  glBindBuffer(GL_ARRAY_BUFFER, cell.buffer);
  glBufferSubData(GL_ARRAY_BUFFER, static_cast<GLintptr>(std::uint64_t{first} * sizeof(Splat)),
                  static_cast<GLsizeiptr>(splats.size_bytes()), splats.data());
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  throwOnGlError("writeToCell");
  cell.count = static_cast<std::uint32_t>(std::max<std::uint64_t>(cell.count, end));
  cell.statisticalStale = true;  // more of the packet holds more nodes
}

void SplatRenderer::forEachCell(const CellVisitor& visit) const {
  context_.makeCurrent();
  std::vector<Splat> splats;
  for (const auto& [id, cell] : cells_) {
    splats.resize(cell.count);
    if (cell.count > 0) {
      glBindBuffer(GL_ARRAY_BUFFER, cell.buffer);
      glGetBufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(splats.size() * sizeof(Splat)),
                         splats.data());
      glBindBuffer(GL_ARRAY_BUFFER, 0);
      throwOnGlError("forEachCell");
    }
    visit(id, splats);
  }
}

void SplatRenderer::releaseCell(std::uint32_t id) {
  const auto it = cells_.find(id);
  if (it == cells_.end()) return;
  context_.makeCurrent();
  uploadedBytes_ -= std::uint64_t{it->second.capacity} * sizeof(Splat);
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
  if (mode == SplatMode::Statistical) {
    if (programs_->statistical == 0) {
      programs_->statistical =
          linkProgram({shaders::kPointEmitVertex, shaders::kStatisticalPointsVertex}, nullptr,
                      shaders::kPointsFragment, "statistical points program");
    }
    return programs_->statistical;
  }
  if (mode == SplatMode::Points || mode == SplatMode::Instanced) {
    if (programs_->points == 0) {
      programs_->points = linkProgram({shaders::kPointEmitVertex, shaders::kPointsVertex}, nullptr,
                                      shaders::kPointsFragment, "points program");
    }
    if (mode == SplatMode::Instanced && programs_->instanced == 0) {
      programs_->instanced =
          linkProgram({shaders::kPointEmitVertex, shaders::kInstancedPointsVertex}, nullptr,
                      shaders::kPointsFragment, "instanced points program");
    }
    return programs_->points;
  }
  if (programs_->splats == 0) {
    programs_->splats = linkProgram({shaders::kSplatsVertex}, shaders::kSplatsGeometry,
                                    shaders::kSplatsFragment, "splats program");
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
  if (settings.mode == SplatMode::Points || settings.mode == SplatMode::Instanced ||
      settings.mode == SplatMode::Statistical) {
    glUniformMatrix4fv(uniform(prog, "viewProjection"), 1, GL_FALSE,
                       glm::value_ptr(viewProjection));
    glUniform1f(uniform(prog, "diameterScale"), 2.0f * focal * scale);
    glUniform1f(uniform(prog, "constantSize"), std::max(settings.pointSize, 0.0f));
    glUniform1f(uniform(prog, "maxSize"),
                std::clamp(std::floor(settings.maxPointSize), 1.0f, maxPointSizeGl_));
    glUniform1i(uniform(prog, "lighting"), settings.lighting ? 1 : 0);
    glUniform1f(uniform(prog, "ambient"), std::clamp(settings.ambient, 0.0f, 1.0f));
    const glm::vec3 eye = cameraEye(camera);  // the CPU kernel's eye, for the same shading
    glUniform3f(uniform(prog, "eye"), eye.x, eye.y, eye.z);
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
    const RenderSettings& settings, std::span<StatisticalDraw> statistical) {
  const auto start = std::chrono::steady_clock::now();
  const bool points = settings.mode == SplatMode::Points || settings.mode == SplatMode::Instanced ||
                      settings.mode == SplatMode::Statistical;
  const bool blended = settings.mode == SplatMode::Blended;
  if (settings.keepDepth && blended) {
    throw UsageError("SplatRenderer: the blended mode keeps no depth of the visible surface");
  }
  if (!settings.keepDepth) depths_.clear();
  context_.resize(rect.width(), rect.height());
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
  if (settings.mode == SplatMode::Instanced) {
    glUseProgram(programs_->instanced);
    setUniforms(programs_->instanced, camera, rect, settings);
  }
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
  glEnableVertexAttribArray(kNormal);

  RenderStats stats;
  std::vector<GLint> firsts;
  std::vector<GLsizei> counts;
  // Splat ranges and the sections' plain remainders first, one multi-draw per
  // cell; then every section's pools with the instanced program (one program
  // switch per frame, not two per section). A tile draws a subset of the
  // frame's draws in the same order, so equal depths resolve as in the frame.
  auto drawAll = [&] {
    if (settings.mode == SplatMode::Statistical) {
      drawStatistical(statistical, stats);
      return;
    }
    bool anySection = false;
    for (const auto& [cell, ranges] : groups) {
      firsts.clear();
      counts.clear();
      for (const DrawRange& range : ranges) {
        if (range.count == 0) continue;
        std::uint64_t first = range.offset, count = range.count;
        if (range.section) {
          anySection = true;
          const Section& s = section(*cell, range);
          first += s.header.remainderOffset / sizeof(Splat);
          count = s.header.remainderCount;
          if (count == 0) continue;
        }
        firsts.push_back(static_cast<GLint>(first));
        counts.push_back(static_cast<GLsizei>(count));
      }
      if (firsts.empty()) continue;
      glBindBuffer(GL_ARRAY_BUFFER, cell->buffer);
      splatAttributes(0);
      glMultiDrawArrays(GL_POINTS, firsts.data(), counts.data(),
                        static_cast<GLsizei>(firsts.size()));
      ++stats.drawCalls;
    }
    if (!anySection) return;
    glUseProgram(programs_->instanced);
    glEnableVertexAttribArray(kTag);
    glEnableVertexAttribArray(kTranslation);
    glVertexAttribDivisor(kTranslation, 1);
    for (const auto& [cell, ranges] : groups) {
      glBindBuffer(GL_ARRAY_BUFFER, cell->buffer);
      for (const DrawRange& range : ranges)
        if (range.section) drawPools(*cell, range, stats);
    }
    glVertexAttribDivisor(kTranslation, 0);
    glDisableVertexAttribArray(kTag);
    glDisableVertexAttribArray(kTranslation);
    glUseProgram(prog);
  };
  // Budget, then cell and node: the frame's global order, which a tile's
  // subset keeps.
  const auto byNode = [](const StatisticalDraw& a, const StatisticalDraw& b) {
    return a.cell != b.cell ? a.cell < b.cell : a.index < b.index;
  };
  if (std::is_sorted(statistical.begin(), statistical.end(), byNode)) {
    // Ranges come in node order: a stable counting sort by budget (at most
    // kStatisticalMaxSamples) gives the order, in memory kept between tiles.
    std::vector<std::uint32_t>& starts = statisticalStarts_;
    starts.assign(kStatisticalMaxSamples + 2, 0);
    for (const StatisticalDraw& d : statistical)
      ++starts[std::min(d.count, kStatisticalMaxSamples) + 1];
    for (std::size_t c = 1; c < starts.size(); ++c) starts[c] += starts[c - 1];
    statisticalSorted_.resize(statistical.size());
    for (const StatisticalDraw& d : statistical)
      statisticalSorted_[starts[std::min(d.count, kStatisticalMaxSamples)]++] = d;
    std::copy(statisticalSorted_.begin(), statisticalSorted_.end(), statistical.begin());
  } else {
    std::sort(statistical.begin(), statistical.end(),
              [&byNode](const StatisticalDraw& a, const StatisticalDraw& b) {
                return a.count != b.count ? a.count < b.count : byNode(a, b);
              });
  }
  for (const StatisticalDraw& node : statistical) stats.splats += node.count;
  for (const auto& group : groups) {
    for (const DrawRange& range : group.second) {
      if (!range.section) {
        stats.splats += range.count;
        continue;
      }
      const Section& s = section(*group.first, range);
      stats.splats += std::uint64_t{s.header.generatedCount} + s.header.remainderCount;
    }
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
      programs_->resolve = linkProgram({shaders::kResolveVertex}, nullptr,
                                       shaders::kResolveFragment, "blend resolve program");
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
  if (settings.keepDepth) {
    const std::size_t count = std::size_t{rect.width()} * rect.height();
    depths_.resize(count);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, static_cast<GLsizei>(rect.width()), static_cast<GLsizei>(rect.height()),
                 GL_DEPTH_COMPONENT, GL_FLOAT, depths_.data());
    // Cleared to 1 and drawn with GL_LESS: 1 is never a drawn pixel's depth.
    const DepthLinearizer linearize(camera);
    for (float& depth : depths_) {
      depth = depth < 1.0f ? linearize(depth) : std::numeric_limits<float>::infinity();
    }
  }
  throwOnGlError("SplatRenderer::render");
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

const SplatRenderer::Section& SplatRenderer::section(const Cell& cell,
                                                     const DrawRange& range) const {
  if (const auto found = cell.sections.find(range.offset); found != cell.sections.end())
    return found->second;
  // Read once from the buffer (llvmpipe: a memcpy), checked whole: the tags
  // the vertex shader tests and every voxel they generate.
  std::vector<Splat> records(range.count);
  glBindBuffer(GL_ARRAY_BUFFER, cell.buffer);
  glGetBufferSubData(GL_ARRAY_BUFFER,
                     static_cast<GLintptr>(std::uint64_t{range.offset} * sizeof(Splat)),
                     static_cast<GLsizeiptr>(records.size() * sizeof(Splat)), records.data());
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  throwOnGlError("reading an instanced section");
  const std::string where =
      "cell " + std::to_string(range.cell) + " at record " + std::to_string(range.offset);
  const InstancedSectionView view = parseInstancedSection(records, where.c_str());
  Section out;
  out.header = view.header;
  const auto* table = reinterpret_cast<const InstancedPool*>(
      reinterpret_cast<const std::byte*>(records.data()) + sizeof(InstancedHeader));
  out.pools.assign(table, table + view.header.poolCount);
  return cell.sections.emplace(range.offset, std::move(out)).first->second;
}

void SplatRenderer::drawPools(const Cell& cell, const DrawRange& range, RenderStats& stats) {
  const Section& s = section(cell, range);
  if (s.pools.empty()) return;
  const std::size_t base = std::size_t{range.offset} * sizeof(Splat);
  const GLuint prog = programs_->instanced;
  glUniform3fv(uniform(prog, "origin"), 1, s.header.origin);
  glUniform3fv(uniform(prog, "high"), 1, s.header.high);
  glUniform1f(uniform(prog, "step"), s.header.step);
  glUniform1f(uniform(prog, "radiusUnit"), s.header.radiusUnit);
  constexpr GLsizei stride = sizeof(InstancedVertex);
  for (const InstancedPool& pool : s.pools) {
    if (pool.vertexCount == 0) continue;
    const std::size_t vertices = base + pool.vertexOffset;
    glVertexAttribIPointer(kPosition, 3, GL_UNSIGNED_SHORT, stride,
                           byteOffset(vertices + offsetof(InstancedVertex, q)));
    glVertexAttribPointer(kColor, 4, GL_UNSIGNED_BYTE, GL_TRUE, stride,
                          byteOffset(vertices + offsetof(InstancedVertex, color)));
    glVertexAttribIPointer(kRadius, 1, GL_UNSIGNED_SHORT, stride,
                           byteOffset(vertices + offsetof(InstancedVertex, radius)));
    glVertexAttribPointer(kNormal, 3, GL_BYTE, GL_TRUE, stride,
                          byteOffset(vertices + offsetof(InstancedVertex, normal)));
    glVertexAttribIPointer(kTag, 2, GL_UNSIGNED_INT, stride,
                           byteOffset(vertices + offsetof(InstancedVertex, tag)));
    glVertexAttribIPointer(kTranslation, 3, GL_SHORT, sizeof(InstancedTranslation),
                           byteOffset(base + pool.translationOffset));
    glDrawArraysInstanced(GL_POINTS, 0, static_cast<GLsizei>(pool.vertexCount),
                          static_cast<GLsizei>(pool.translationCount));
    ++stats.drawCalls;
  }
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
      if (sorted[j].section && settings.mode != SplatMode::Instanced) {
        throw UsageError("SplatRenderer::render: an instanced section outside --mode instanced");
      }
      if (settings.mode == SplatMode::Statistical) continue;  // node ranges: checked below
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
  if (settings.mode != SplatMode::Statistical) return draw(camera, rect, groups, settings);

  context_.makeCurrent();
  const FootprintProjector project(camera);
  std::vector<StatisticalDraw>& draws = statisticalDraws_;  // its capacity kept
  draws.clear();
  for (const auto& [cell, cellRanges] : groups) {
    for (const DrawRange& range : cellRanges) {
      if (range.count == 0) continue;
      const StatisticalPacketView& view = statisticalNodes(*cell, range.cell);
      if (std::uint64_t{range.offset} + range.count > view.nodes.size()) {
        throw UsageError("SplatRenderer::render: node range [" + std::to_string(range.offset) +
                         ", +" + std::to_string(range.count) + ") outside cell " +
                         std::to_string(range.cell) + " of " + std::to_string(view.nodes.size()) +
                         " decoded statistical nodes");
      }
      for (std::uint32_t k = range.offset; k < range.offset + range.count; ++k) {
        const StatisticalNode& node = view.nodes[k];
        const PointBudget budget = nodePointBudget(node, project);
        draws.push_back({budget.count, range.cell, k, budget.pointPixels, &node});
      }
    }
  }
  return draw(camera, rect, {}, settings, draws);
}

void SplatRenderer::setStatisticalClasses(std::shared_ptr<const ClassTables> classes) {
  statisticalClasses_ = std::move(classes);
  for (auto& entry : cells_) entry.second.statistical.reset();
}

void SplatRenderer::setStatisticalSamples(std::vector<GaussianSample> samples) {
  if (samples.empty()) throw UsageError("setStatisticalSamples: no samples");
  if (samples.size() > static_cast<std::size_t>(INT_MAX)) {
    throw UsageError("setStatisticalSamples: more than 2^31 samples");
  }
  samples_ = std::move(samples);
  if (sampleBuffer_ != 0) {
    context_.makeCurrent();
    glDeleteBuffers(1, &sampleBuffer_);
    sampleBuffer_ = 0;
  }
}

const StatisticalPacketView& SplatRenderer::statisticalNodes(const Cell& cell,
                                                             std::uint32_t id) const {
  if (cell.statistical && !cell.statisticalStale) return *cell.statistical;
  if (!statisticalClasses_) {
    throw UsageError(
        "SplatRenderer: the statistical mode needs the class tables (setStatisticalClasses)");
  }
  // Read once from the buffer (llvmpipe: a memcpy) and decoded whole.
  std::vector<Splat> records(cell.count);
  if (!records.empty()) {
    glBindBuffer(GL_ARRAY_BUFFER, cell.buffer);
    glGetBufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(records.size() * sizeof(Splat)),
                       records.data());
    glBindBuffer(GL_ARRAY_BUFFER, 0);
    throwOnGlError("reading a statistical packet");
  }
  if (!cell.statistical) cell.statistical = std::make_shared<StatisticalPacketView>();
  cell.statisticalStale = false;
  extendStatisticalPacket(*cell.statistical, std::as_bytes(std::span<const Splat>(records)),
                          *statisticalClasses_, "cell " + std::to_string(id));
  return *cell.statistical;
}

void SplatRenderer::drawStatistical(std::span<const StatisticalDraw> draws, RenderStats& stats) {
  if (draws.empty()) return;
  if (sampleBuffer_ == 0) {
    if (samples_.empty()) samples_ = gaussianSamples(kStatisticalMaxSamples);
    glGenBuffers(1, &sampleBuffer_);
    glBindBuffer(GL_ARRAY_BUFFER, sampleBuffer_);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(samples_.size() * sizeof(GaussianSample)),
                 samples_.data(), GL_STATIC_DRAW);
    sampleCount_ = static_cast<std::uint32_t>(samples_.size());
    samples_.clear();
    samples_.shrink_to_fit();
  }
  // Memory kept from tile to tile: fresh pages cost more than the copy.
  static_assert(sizeof(StatisticalInstance) % sizeof(float) == 0);
  constexpr std::size_t floats = sizeof(StatisticalInstance) / sizeof(float);
  instanceScratch_.resize(draws.size() * floats);
  for (std::size_t i = 0; i < draws.size(); ++i) {
    const StatisticalInstance instance = statisticalInstance(*draws[i].node, draws[i].pointPixels);
    std::memcpy(instanceScratch_.data() + i * floats, &instance, sizeof instance);
  }
  const std::size_t bytes = instanceScratch_.size() * sizeof(float);
  if (instanceBuffer_ == 0) glGenBuffers(1, &instanceBuffer_);
  glBindBuffer(GL_TEXTURE_BUFFER, instanceBuffer_);
  if (bytes > instanceCapacity_) {
    instanceCapacity_ = bytes + bytes / 2;
    glBufferData(GL_TEXTURE_BUFFER, static_cast<GLsizeiptr>(instanceCapacity_), nullptr,
                 GL_STREAM_DRAW);
  }
  glBufferSubData(GL_TEXTURE_BUFFER, 0, static_cast<GLsizeiptr>(bytes), instanceScratch_.data());
  glBindBuffer(GL_TEXTURE_BUFFER, 0);
  if (nodeTexture_ == 0) glGenTextures(1, &nodeTexture_);
  if (sampleTexture_ == 0) glGenTextures(1, &sampleTexture_);
  // Attached every time: the sample buffer may have been replaced.
  glActiveTexture(GL_TEXTURE0 + kStatisticalNodeUnit);
  glBindTexture(GL_TEXTURE_BUFFER, nodeTexture_);
  glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, instanceBuffer_);
  glActiveTexture(GL_TEXTURE0 + kStatisticalSampleUnit);
  glBindTexture(GL_TEXTURE_BUFFER, sampleTexture_);
  glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, sampleBuffer_);
  glActiveTexture(GL_TEXTURE0);
  const GLuint program = programs_->statistical;
  glUniform1i(uniform(program, "statisticalNodes"), kStatisticalNodeUnit);
  glUniform1i(uniform(program, "statisticalSamples"), kStatisticalSampleUnit);
  const GLint firstNode = uniform(program, "statisticalFirstNode");
  const GLint perNode = uniform(program, "statisticalCount");
  // No vertex arrays: everything comes from gl_VertexID and the textures.
  for (GLuint a = 0; a < kStatisticalAttributes; ++a) glDisableVertexAttribArray(a);
  // One draw per distinct budget (draws are sorted by it): node after node,
  // each node's samples in order, as an instanced draw would order them.
  for (std::size_t i = 0; i < draws.size();) {
    std::size_t j = i + 1;
    while (j < draws.size() && draws[j].count == draws[i].count) ++j;
    const auto vertices = static_cast<GLsizei>(std::min(draws[i].count, sampleCount_));
    glUniform1i(firstNode, static_cast<GLint>(i));
    glUniform1i(perNode, vertices);
    glDrawArrays(GL_POINTS, 0, vertices * static_cast<GLsizei>(j - i));
    ++stats.drawCalls;
    i = j;
  }
  for (GLuint a = 0; a <= kNormal; ++a) glEnableVertexAttribArray(a);
}

RenderStats SplatRenderer::renderNodes(const Camera& camera, const TileRect& rect,
                                       std::span<const StatisticalNode> nodes,
                                       const RenderSettings& settings,
                                       std::span<const PointBudget> budgets) {
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("SplatRenderer::renderNodes: tile rectangle is empty or outside the image");
  }
  if (!budgets.empty() && budgets.size() != nodes.size()) {
    throw UsageError("SplatRenderer::renderNodes: " + std::to_string(budgets.size()) +
                     " budgets for " + std::to_string(nodes.size()) + " nodes");
  }
  if (nodes.size() > std::numeric_limits<std::uint32_t>::max()) {
    throw UsageError("SplatRenderer::renderNodes: more than 2^32 nodes");
  }
  context_.makeCurrent();
  const FootprintProjector project(camera);
  std::vector<StatisticalDraw> draws;
  draws.reserve(nodes.size());
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    const PointBudget budget = budgets.empty() ? nodePointBudget(nodes[i], project) : budgets[i];
    if (budget.count == 0) continue;
    draws.push_back(
        {budget.count, 0, static_cast<std::uint32_t>(i), budget.pointPixels, &nodes[i]});
  }
  RenderSettings statistical = settings;
  statistical.mode = SplatMode::Statistical;
  return draw(camera, rect, {}, statistical, draws);
}

RenderStats SplatRenderer::renderSplats(const Camera& camera, const TileRect& rect,
                                        std::span<const Splat> splats,
                                        const RenderSettings& settings) {
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("SplatRenderer::renderSplats: tile rectangle is empty or outside the image");
  }
  if (settings.mode == SplatMode::Statistical) {
    throw UsageError("SplatRenderer::renderSplats: statistical nodes are drawn by renderNodes");
  }
  context_.makeCurrent();
  upload(scratch_, splats);
  const DrawRange all{0, 0, scratch_.count};
  const std::pair<const Cell*, std::span<const DrawRange>> group{&scratch_, {&all, 1}};
  return draw(camera, rect, {&group, 1}, settings);
}

std::string SplatRenderer::describe() const {
  return "gl: GL " + context_.versionString() + " on " + context_.rendererString();
}

void SplatRenderer::warmUp(const RenderSettings& settings) {
  const Camera camera = makeCamera({0.0f, 0.0f, 2.0f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f},
                                   60.0f, 0.1f, 10.0f, 8, 8);
  if (settings.mode == SplatMode::Statistical) {
    StatisticalNode node{};
    for (int k = 0; k < 3; ++k) {
      node.axes[k][k] = node.normalFrame[k][k] = node.colorAxes[k][k] = 1.0f;
      node.sigma[k] = 0.05f;
    }
    node.color[0] = 255.0f;
    renderNodes(camera, makeTileRect(0, 0, 8, 8), {&node, 1}, settings);
    return;
  }
  Splat splat{};
  splat.normal[2] = 1.0f;
  splat.radius = 0.1f;
  splat.color[0] = splat.color[3] = 255;
  renderSplats(camera, makeTileRect(0, 0, 8, 8), {&splat, 1}, settings);
}

}  // namespace pointillist::render
