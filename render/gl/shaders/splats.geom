#version 330 core
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
