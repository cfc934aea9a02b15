#version 330 core
// Seed 004 §8.2: statistical point generation. The samples are a static
// buffer of standard-normal vectors (common/statistical_samples.hpp, Sobol);
// the nodes of a draw, the formulas at StatisticalNode in
// common/statistical_node.hpp with the axes pre-scaled by their sigmas, are a
// buffer texture written per tile. A draw of statisticalCount points per node
// generates vertex v from node statisticalFirstNode + v / statisticalCount and
// sample v % statisticalCount: node after node, as an instanced draw would,
// without llvmpipe's cost per instance.
uniform samplerBuffer statisticalNodes;    // 10 RGBA32F texels per node
uniform samplerBuffer statisticalSamples;  // 2 RGBA32F texels per sample
uniform int statisticalFirstNode;
uniform int statisticalCount;
void emitPointPixels(vec3 position, vec4 color, float pixels, vec3 normal);
void main() {
  int k = gl_VertexID / statisticalCount;
  int s = gl_VertexID - k * statisticalCount;
  int node = (statisticalFirstNode + k) * 10;
  vec4 mean = texelFetch(statisticalNodes, node);  // w: point width in pixels
  vec4 axis0 = texelFetch(statisticalNodes, node + 1);  // axes[k] * sigma[k]; w: colour
  vec4 axis1 = texelFetch(statisticalNodes, node + 2);
  vec4 axis2 = texelFetch(statisticalNodes, node + 3);
  vec3 normalX = texelFetch(statisticalNodes, node + 4).xyz;  // normalFrame[0] * sigmaNormal[0]
  vec3 normalY = texelFetch(statisticalNodes, node + 5).xyz;  // normalFrame[1] * sigmaNormal[1]
  vec3 normalZ = texelFetch(statisticalNodes, node + 6).xyz;  // the mean normal
  vec3 colorAxis0 = texelFetch(statisticalNodes, node + 7).xyz;  // colorAxes[k] * sigmaColor[k]
  vec3 colorAxis1 = texelFetch(statisticalNodes, node + 8).xyz;
  vec3 colorAxis2 = texelFetch(statisticalNodes, node + 9).xyz;
  // GaussianSample: position xyz, normal xy, colour xyz.
  vec4 sample0 = texelFetch(statisticalSamples, 2 * s);
  vec4 sample1 = texelFetch(statisticalSamples, 2 * s + 1);
  vec3 position = mean.xyz + axis0.xyz * sample0.x + axis1.xyz * sample0.y + axis2.xyz * sample0.z;
  // The tangent-plane sample wrapped onto the sphere around the mean normal.
  vec3 tangent = normalX * sample0.w + normalY * sample1.x;
  float theta = length(tangent);
  vec3 normal = normalZ * cos(theta);
  if (theta > 0.0) normal += tangent * (sin(theta) / theta);
  vec3 color = vec3(axis0.w, axis1.w, axis2.w) + colorAxis0 * sample1.y +
               colorAxis1 * sample1.z + colorAxis2 * sample1.w;
  color = clamp(color, 0.0, 255.0) * (1.0 / 255.0);
  emitPointPixels(position, vec4(color, 1.0), mean.w, normal);
}
