#version 460
#extension GL_GOOGLE_include_directive : require
// Chapter 12's composite as a Vulkan compute shader, for the measurement that compares it with
// GL's (`--vulkan-composite-rounds`): the same code (composite_tile.glsl), the surface read as
// a storage image, the settings as push constants.

layout(local_size_x = 16, local_size_y = 16) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image2D surface;
layout(set = 0, binding = 1, rgba8) uniform writeonly image2D picture;
#define SURFACE(p) imageLoad(surface, p)
#define SURFACE_SIZE imageSize(surface)

// The fields of composite.rs's Uniforms, as vk_composite.rs packs them.
layout(push_constant) uniform Settings {
    int blur_radius;
    float depth_tolerance;
    float normal_tolerance;
    float power;
    int view;
    float far_depth;
};

#include "composite_tile.glsl"
