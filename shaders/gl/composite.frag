#version 450 core
// Chapter 08: albedo x ambient occlusion, the occlusion blurred without bleeding across edges.

layout(binding = 0) uniform sampler2D positions; // xyz world, w view depth (0: background)
layout(binding = 1) uniform sampler2D normals;
layout(binding = 2) uniform sampler2D albedo;
layout(binding = 3) uniform sampler2D ao;        // running mean of visibility, from Vulkan

uniform int blur_radius;          // 0: no blur at all
uniform float depth_tolerance;    // relative: a neighbour counts if |dz| <= tolerance * z
uniform float normal_tolerance;   // a neighbour counts if dot(n, n') >= this
uniform float power;              // contrast of the occlusion
uniform int view;                 // 0 final, 1 position, 2 normal, 3 depth, 4 albedo, 5 AO
uniform vec3 bounds_low;          // for showing positions as colours
uniform vec3 bounds_high;
uniform float far_depth;          // for showing depth

layout(location = 0) out vec4 colour;

const vec3 BACKGROUND = vec3(0.06, 0.07, 0.09);

void main() {
    // Texel (x, y) of the G-buffers is pixel (x, y) here: same size, same row order.
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 position = texelFetch(positions, pixel, 0);
    if (position.w <= 0.0) {
        colour = vec4(BACKGROUND, 1.0);
        return;
    }
    vec3 normal = texelFetch(normals, pixel, 0).xyz;

    // A symmetric window, [-r, r] on both axes, the centre counted once. A neighbour joins the
    // average only if it lies on the same surface: its view depth within a fraction of ours
    // (relative, so the test means the same near and far), and its normal close to ours.
    ivec2 last = textureSize(ao, 0) - 1;
    float sum = 0.0;
    float count = 0.0;
    for (int dy = -blur_radius; dy <= blur_radius; dy++) {
        for (int dx = -blur_radius; dx <= blur_radius; dx++) {
            ivec2 q = clamp(pixel + ivec2(dx, dy), ivec2(0), last);
            vec4 p = texelFetch(positions, q, 0);
            bool same_depth = p.w > 0.0 && abs(p.w - position.w) <= depth_tolerance * position.w;
            bool same_facing = dot(texelFetch(normals, q, 0).xyz, normal) >= normal_tolerance;
            if (same_depth && same_facing) {
                sum += texelFetch(ao, q, 0).r;
                count += 1.0;
            }
        }
    }
    // The centre always qualifies, so count >= 1.
    float occlusion = pow(sum / count, power);
    vec3 base = texelFetch(albedo, pixel, 0).rgb;

    vec3 shown = base * occlusion;
    if (view == 1) shown = (position.xyz - bounds_low) / max(bounds_high - bounds_low, vec3(1e-9));
    if (view == 2) shown = normal * 0.5 + 0.5;
    if (view == 3) shown = vec3(1.0 - position.w / far_depth);
    if (view == 4) shown = base;
    if (view == 5) shown = vec3(occlusion);
    colour = vec4(shown, 1.0);
}
