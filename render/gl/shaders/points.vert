#version 330 core
// One splat per vertex (point_emit.vert does the rest).
layout(location = 0) in vec3 inPosition;
layout(location = 1) in vec4 inColor;
layout(location = 2) in float inRadius;
layout(location = 3) in vec3 inNormal;
void emitPoint(vec3 position, vec4 color, float radius, vec3 normal);
void main() { emitPoint(inPosition, inColor, inRadius, inNormal); }
