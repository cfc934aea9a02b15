#version 330 core
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
