#version 330 core
// Seed 000 §3: a pool's vertex stream (per vertex) times its transformation
// stream (per instance). Instance i applies to a vertex only when bit i of the
// vertex's tag is set; otherwise the point is sent outside the clip volume.
// Layouts: common/instanced_section.hpp.
layout(location = 0) in uvec3 inVoxel;      // InstancedVertex::q
layout(location = 1) in vec4 inColor;       // RGBA8
layout(location = 2) in uint inRadius;      // in radiusUnit
layout(location = 3) in vec3 inNormal;      // snorm8
layout(location = 4) in uvec2 inTag;
layout(location = 5) in ivec3 inTranslation;  // per instance
uniform vec3 origin;
uniform vec3 high;  // decoded voxels are clamped to the unit's points' bounds
uniform float step;
uniform float radiusUnit;
void emitPoint(vec3 position, vec4 color, float radius, vec3 normal);
void main() {
  uint word = gl_InstanceID < 32 ? inTag.x : inTag.y;
  if (((word >> uint(gl_InstanceID & 31)) & 1u) == 0u) {
    gl_PointSize = 1.0;
    gl_Position = vec4(0.0, 0.0, 2.0, 1.0);  // not this vertex's translation: clipped
    return;
  }
  vec3 voxel = vec3(ivec3(inVoxel) + inTranslation);
  vec3 position = clamp(origin + voxel * step, origin, high);
  emitPoint(position, inColor, float(inRadius) * radiusUnit, inNormal);
}
