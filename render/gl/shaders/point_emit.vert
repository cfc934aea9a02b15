#version 330 core
// The points mode's vertex work, shared by points.vert, instanced_points.vert
// and statistical_points.vert (linked into the same program): projection,
// size, snapping and headlight.
uniform mat4 viewProjection;
uniform vec2 frameSize;
uniform float guard;          // pixels of clip volume beyond each frame edge
uniform float diameterScale;  // 2 * focal length in pixels * sizeScale
uniform float constantSize;   // > 0: fixed size
uniform float maxSize;
uniform int lighting;         // headlight: ambient + (1 - ambient) * |n . toEye|
uniform float ambient;
uniform vec3 eye;
flat out vec4 vColor;
// A point `size` pixels wide (rounded, in [1, maxSize]) at `position`.
void emitClipPoint(vec4 clip, vec3 position, vec4 color, float size, vec3 normal) {
  float shade = 1.0;
  if (lighting != 0 && dot(normal, normal) > 0.25) {  // no normal: unshaded
    vec3 toEye = eye - position;
    float distance = length(toEye);
    if (distance > 0.0) {
      shade = ambient + (1.0 - ambient) * abs(dot(normalize(normal), toEye / distance));
    }
  }
  vColor = vec4(color.rgb * shade, color.a);
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
// A splat: its projected diameter (or constantSize) wide.
void emitPoint(vec3 position, vec4 color, float radius, vec3 normal) {
  vec4 clip = viewProjection * vec4(position, 1.0);
  float size = constantSize > 0.0 ? constantSize : radius * diameterScale / clip.w;
  emitClipPoint(clip, position, color, size, normal);
}
// A point `pixels` wide whatever its distance.
void emitPointPixels(vec3 position, vec4 color, float pixels, vec3 normal) {
  emitClipPoint(viewProjection * vec4(position, 1.0), position, color, pixels, normal);
}
