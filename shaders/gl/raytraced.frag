#version 450 core
// Chapter 11: the ray tracer's colour, and the depth GL's rasteriser would have written for the
// point each ray hit, so that lines drawn next are hidden by ray-traced surfaces exactly as by
// rasterised ones. The ray tracer wrote, per pixel, its colour and the hit distance t.

// Path 1 (PBO): GL copied the tracer's buffer into two textures.
layout(binding = 0) uniform sampler2D traced_colour;
layout(binding = 1) uniform sampler2D traced_distance;
// Path 2 (zero-copy): the tracer's buffer itself (width * height colours, then as many distances).
layout(std430, binding = 0) readonly buffer Traced { uint traced[]; };
uniform bool from_buffer;

uniform ivec2 size;
// tan(fov_y / 2) * aspect, tan(fov_y / 2): the ray tracer's `right` and `up` lengths.
uniform vec2 tan_half;
uniform float near_plane;
uniform float far_plane;

layout(location = 0) out vec4 colour;

// ANCHOR: depth
// Hit distance t along the ray through ndc (x, y in -1..1) -> window depth, as scene.rs derives.
float window_depth(float t, vec2 ndc) {
    float view_depth = t / length(vec3(ndc * tan_half, 1.0));
    return far_plane * (view_depth - near_plane) / ((far_plane - near_plane) * view_depth);
}
// ANCHOR_END: depth

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 rgba;
    float t;
    if (from_buffer) {
        int i = pixel.y * size.x + pixel.x;
        rgba = unpackUnorm4x8(traced[i]); // red in the lowest byte, as the tracer packed it
        t = uintBitsToFloat(traced[size.x * size.y + i]);
    } else {
        rgba = texelFetch(traced_colour, pixel, 0);
        t = texelFetch(traced_distance, pixel, 0).r;
    }
    colour = vec4(rgba.rgb, 1.0);
    vec2 ndc = (vec2(pixel) + 0.5) / vec2(size) * 2.0 - 1.0;
    // t = 0: the ray hit nothing; the far plane, behind every line.
    gl_FragDepth = t > 0.0 ? window_depth(t, ndc) : 1.0;
}
