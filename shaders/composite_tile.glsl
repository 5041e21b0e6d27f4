// Chapter 12's composite, the part GL's compute shader (shaders/gl/fast_composite.comp) and
// Vulkan's (fast_composite.comp) share: albedo x ambient occlusion, the occlusion blurred
// without bleeding across edges, as chapter 08's composite.frag computes it. A 16x16 group
// loads its pixels and a border of blur_radius around them into shared memory once, and every
// pixel's window is read from there: each texel is fetched once per group, not once per
// neighbour.
//
// The including shader declares, its own way: SURFACE(p) and SURFACE_SIZE (the surface Vulkan
// traced: x visibility, y view depth (0: background), z packed normal, w albedo as 0xBBGGRR),
// `picture` (RGBA8, written), and blur_radius (0 to MAX_RADIUS), depth_tolerance (relative: a
// neighbour counts if |dz| <= tolerance * z), normal_tolerance (a neighbour counts if
// dot(n, n') >= this), power (contrast of the occlusion), view (0 final, 1 AO, 2 view depth,
// 3 normal, 4 albedo) and far_depth (for showing depth).

const int MAX_RADIUS = 8;
const int SIDE = 16 + 2 * MAX_RADIUS;
shared vec2 visibility_depth[SIDE * SIDE];
shared vec3 normals[SIDE * SIDE];

const vec3 BACKGROUND = vec3(0.06, 0.07, 0.09);

// unpack_normal, chapter 07's.
#include "sampling.glsl"

void main() {
    ivec2 size = SURFACE_SIZE;
    int side = 16 + 2 * blur_radius;
    // ANCHOR: tile
    // The group's pixels and their border, clamped at the picture's edges as composite.frag
    // clamps: 256 threads load (16 + 2r)^2 texels between them, then wait for each other.
    ivec2 corner = ivec2(gl_WorkGroupID.xy) * 16 - blur_radius;
    for (int i = int(gl_LocalInvocationIndex); i < side * side; i += 256) {
        ivec2 q = clamp(corner + ivec2(i % side, i / side), ivec2(0), size - 1);
        vec4 s = SURFACE(q);
        visibility_depth[i] = s.xy;
        normals[i] = s.y > 0.0 ? unpack_normal(uint(s.z)) : vec3(0.0);
    }
    barrier();
    // ANCHOR_END: tile
    ivec2 pixel = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(pixel, size))) {
        return; // past the picture's edge (after the barrier: every thread must reach it)
    }
    ivec2 at = ivec2(gl_LocalInvocationID.xy) + blur_radius;
    vec2 centre = visibility_depth[at.y * side + at.x];
    if (centre.y <= 0.0) {
        imageStore(picture, pixel, vec4(BACKGROUND, 1.0));
        return;
    }
    vec3 normal = normals[at.y * side + at.x];
    // ANCHOR: blur
    // composite.frag's symmetric window and its two tests, on the tile.
    float sum = 0.0;
    float count = 0.0;
    for (int dy = -blur_radius; dy <= blur_radius; dy++) {
        for (int dx = -blur_radius; dx <= blur_radius; dx++) {
            int j = (at.y + dy) * side + at.x + dx;
            vec2 other = visibility_depth[j];
            bool same_depth = other.y > 0.0 && abs(other.y - centre.y) <= depth_tolerance * centre.y;
            bool same_facing = dot(normals[j], normal) >= normal_tolerance;
            if (same_depth && same_facing) {
                sum += other.x;
                count += 1.0;
            }
        }
    }
    // ANCHOR_END: blur
    float occlusion = pow(sum / count, power); // the centre always counts: count >= 1
    uint rgb = uint(SURFACE(pixel).w);
    vec3 albedo = vec3(rgb & 0xFFu, (rgb >> 8) & 0xFFu, (rgb >> 16) & 0xFFu) / 255.0;
    vec3 shown = albedo * occlusion;
    if (view == 1) shown = vec3(occlusion);
    if (view == 2) shown = vec3(1.0 - centre.y / far_depth);
    if (view == 3) shown = normal * 0.5 + 0.5;
    if (view == 4) shown = albedo;
    imageStore(picture, pixel, vec4(shown, 1.0));
}
