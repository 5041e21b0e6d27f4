// A unit normal in 24 bits and back: GL's G-buffer pass packs the triangle's own normal
// (chapter 07), chapters 12 and 13's ray generation shaders pack it into the surface image, and
// the ray generation shaders and the composite unpack it. One copy for both APIs: glslc includes
// it for Vulkan, `base::gl::with_includes` for GL.

vec2 sign_not_zero(vec2 v) {
    return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

// ANCHOR: pack_normal
// A unit vector in one float: the octahedral map (Cigolle et al., JCGT 2014) folds the sphere onto
// the square [-1, 1]^2; each coordinate is rounded to 12 bits and the pair stored as the integer
// x * 4096 + y, below 2^24, which a float holds exactly (`float(pack_normal(n))`). The angle lost
// to rounding is under 0.1 degree, far below what moving a ray's origin off the surface or
// choosing its direction needs.
uint pack_normal(vec3 n) {
    vec2 p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    if (n.z < 0.0) {
        p = (1.0 - abs(p.yx)) * sign_not_zero(p);
    }
    uvec2 q = uvec2(round(clamp(p * 0.5 + 0.5, 0.0, 1.0) * 4095.0));
    return q.x * 4096u + q.y;
}
// ANCHOR_END: pack_normal

// (`bits`, not `packed`: GL's GLSL reserves that word.)
vec3 unpack_normal(uint bits) {
    vec2 p = vec2(bits >> 12u, bits & 4095u) / 4095.0 * 2.0 - 1.0;
    vec3 n = vec3(p, 1.0 - abs(p.x) - abs(p.y));
    if (n.z < 0.0) {
        n.xy = (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    }
    return normalize(n);
}
