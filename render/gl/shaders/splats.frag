#version 330 core
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
