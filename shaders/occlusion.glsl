// Chapters 12 and 13: a point's occlusion rays, for the ray generation shaders that include
// surface_hit.glsl (its sequence, hash and basis) first, and declare the acceleration structure
// `scene` and the payload `hit` before it. Apart from surface_hit.glsl because a shader that
// traces no ray includes that alone.

// `samples` occlusion rays from `origin` over the hemisphere about `n`, cosine-weighted, taking
// the R2 points [first, first + samples) of the sequence turned by `rotation`, each moved by
// `jitter`; returns how many found an occluder within `radius`.
uint occluded_rays(vec3 origin, vec3 n, float radius, uint first, uint samples,
                   uvec2 rotation, vec2 jitter) {
    vec3 t, b;
    basis(n, t, b);
    uint flags = gl_RayFlagsOpaqueEXT | gl_RayFlagsTerminateOnFirstHitEXT | gl_RayFlagsSkipClosestHitShaderEXT;
    uint hits = 0u;
    for (uint s = 0u; s < samples; s++) {
        vec2 r = fract(r2(first + s, rotation) + jitter);
        float radial = sqrt(r.x);
        float phi = 6.28318530718 * r.y;
        vec3 dir = t * (radial * cos(phi)) + b * (radial * sin(phi)) + n * sqrt(max(0.0, 1.0 - r.x));
        hit = 1u; // "occluded" until the miss shader says otherwise
        traceRayEXT(scene, flags, 0xFF, 0, 0, 0, origin, 0.0, dir, radius, 0);
        hits += hit;
    }
    return hits;
}
