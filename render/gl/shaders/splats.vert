#version 330 core
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
