#version 450 core
// Chapter 16's check of GL's sampling: one textureLod per point, at the texture coordinate and
// level of detail the CPU chose (xy, z), with the texture's own sampler state (trilinear, REPEAT).
layout(local_size_x = 64) in;

layout(binding = 0) uniform sampler2D picture;
layout(std430, binding = 0) readonly buffer Points { vec4 points[]; };
layout(std430, binding = 1) writeonly buffer Samples { vec4 samples[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < uint(points.length())) {
        samples[i] = textureLod(picture, points[i].xy, points[i].z); // sRGB decoded, then filtered
    }
}
