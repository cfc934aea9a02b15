#version 330 core
in vec2 uv;
uniform sampler2D accumulation;
uniform vec4 clearColor;
out vec4 fragColor;
void main() {
  vec4 sum = texture(accumulation, uv);
  fragColor = sum.a > 0.0 ? vec4(sum.rgb / sum.a, 1.0) : clearColor;
}
