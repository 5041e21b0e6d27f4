#version 450 core
// Chapter 12's composite as a GL compute shader: the surface is sampled, the settings are
// uniforms. The rest, shared with Vulkan's fast_composite.comp, is shaders/composite_tile.glsl,
// included below. GL has no #include: composite.rs resolves it (with_includes) before compiling.

layout(local_size_x = 16, local_size_y = 16) in;

// From Vulkan: x visibility (running mean), y view depth (0: background), z packed normal,
// w albedo as 0xBBGGRR (visibility_ao.rgen).
layout(binding = 0) uniform sampler2D surface;
layout(binding = 0, rgba8) uniform writeonly image2D picture;
#define SURFACE(p) texelFetch(surface, p, 0)
#define SURFACE_SIZE textureSize(surface, 0)

uniform int blur_radius;        // 0 to MAX_RADIUS
uniform float depth_tolerance;  // relative: a neighbour counts if |dz| <= tolerance * z
uniform float normal_tolerance; // a neighbour counts if dot(n, n') >= this
uniform float power;            // contrast of the occlusion
uniform int view;               // 0 final, 1 AO, 2 view depth, 3 normal, 4 albedo
uniform float far_depth;        // for showing depth

#include "composite_tile.glsl"
