// ANCHOR: all
// What every ray generation shader that traces occlusion shares, chapter 07's ao.rgen and, through
// surface_hit.glsl, chapters 12 and 13: where a ray starts, the normal it starts along, and the
// sample sequence. One copy: the checks that compare the chapters' occlusion rely on every
// chapter tracing the same rays.

// ANCHOR: offset
// How far to lift a ray's origin off the surface it starts on. GL's interpolated position is
// off the true surface by rounding: a few float steps of the largest coordinate involved, the
// point's own or, for a triangle around the origin, its corners' (bounded by the scene's size,
// `scene_scale`). 2^-16 of that is about a hundred such steps, so the ray clears the surface,
// and it is relative, so it means the same at a scale of 1e-4 and of 1e4. The scene is re-centred
// on the CPU (`Scene::new`), so a model far from the world's origin keeps small coordinates here.
// At most a thousandth of the radius: an offset that large would skip real occluders.
float ray_offset(vec3 p, float scene_scale, float radius) {
    float largest = max(max(abs(p.x), abs(p.y)), max(abs(p.z), scene_scale));
    return min(largest * (1.0 / 65536.0), 1e-3 * radius);
}
// ANCHOR_END: offset

// sign_not_zero, pack_normal and unpack_normal: the normal in 24 bits, GL's and Vulkan's.
#include "octahedral.glsl"

// A per-pixel hash (PCG), to give each pixel its own rotation of the sample sequence.
uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// ANCHOR: r2
// The R2 sequence (Roberts, 2018): a low-discrepancy 2D sequence, point i = fract(0.5 + i * alpha).
// In fixed point: alpha * 2^32 as integers, so the products wrap exactly, and point 10^9 is as
// good as point 10. (In floats, `alpha * float(i)` keeps only 24 bits: past a million samples
// the points would collapse onto a coarse grid.) `rotation` shifts the whole sequence per pixel
// (Cranley-Patterson), in the same fixed point. The top 24 bits become a float in [0, 1).
vec2 r2(uint index, uvec2 rotation) {
    uvec2 fixed_point = uvec2(index * 3242174889u, index * 2447445414u) + 2147483648u + rotation;
    return vec2(fixed_point >> 8u) * (1.0 / 16777216.0);
}
// ANCHOR_END: r2

// An orthonormal basis around n without branches on n (Duff et al., JCGT 2017).
void basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}
// ANCHOR_END: all
