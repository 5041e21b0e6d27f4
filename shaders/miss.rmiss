#version 460
#extension GL_EXT_ray_tracing : require
// Chapters 06 and 07: a ray that hits nothing clears the "hit" its ray generation shader preset.

layout(location = 0) rayPayloadInEXT uint hit;

void main() {
    hit = 0u;
}
