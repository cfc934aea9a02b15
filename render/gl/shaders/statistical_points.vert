#version 330 core
// Seed 004 §8.2: statistical point generation. The vertices are a static
// buffer of standard-normal samples (common/statistical_samples.hpp, Sobol);
// each instance is one PCA node (the formulas at StatisticalNode in
// common/statistical_node.hpp), its axes pre-scaled by their sigmas. Instance
// i of a draw of n vertices is node i's first n samples.
layout(location = 0) in vec3 inSample;        // GaussianSample::position (per vertex)
layout(location = 1) in vec2 inSampleNormal;  // GaussianSample::normal
layout(location = 2) in vec3 inSampleColor;   // GaussianSample::color
layout(location = 3) in vec4 inMean;          // per instance: mean, point width in pixels
layout(location = 4) in vec3 inAxis0;         // axes[k] * sigma[k]
layout(location = 5) in vec3 inAxis1;
layout(location = 6) in vec3 inAxis2;
layout(location = 7) in vec3 inNormalX;       // normalFrame[0] * sigmaNormal[0]
layout(location = 8) in vec3 inNormalY;       // normalFrame[1] * sigmaNormal[1]
layout(location = 9) in vec3 inNormalZ;       // normalFrame[2], the mean normal
layout(location = 10) in vec3 inColor;        // RGB 0..255
layout(location = 11) in vec3 inColorAxis0;   // colorAxes[k] * sigmaColor[k]
layout(location = 12) in vec3 inColorAxis1;
layout(location = 13) in vec3 inColorAxis2;
void emitPointPixels(vec3 position, vec4 color, float pixels, vec3 normal);
void main() {
  vec3 position = inMean.xyz + inAxis0 * inSample.x + inAxis1 * inSample.y + inAxis2 * inSample.z;
  // The tangent-plane sample wrapped onto the sphere around the mean normal.
  vec3 tangent = inNormalX * inSampleNormal.x + inNormalY * inSampleNormal.y;
  float theta = length(tangent);
  vec3 normal = inNormalZ * cos(theta);
  if (theta > 0.0) normal += tangent * (sin(theta) / theta);
  vec3 color = inColor + inColorAxis0 * inSampleColor.x + inColorAxis1 * inSampleColor.y +
               inColorAxis2 * inSampleColor.z;
  color = clamp(color, 0.0, 255.0) * (1.0 / 255.0);
  emitPointPixels(position, vec4(color, 1.0), inMean.w, normal);
}
