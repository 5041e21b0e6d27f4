// Chapters 12 and 13: what a ray generation shader needs to rebuild a pixel's hit from the id GL
// drew there, and to trace its occlusion. Included by visibility_ao.rgen and temporal_ao.rgen
// (both need GL_EXT_buffer_reference and GL_EXT_buffer_reference_uvec2, and declare the
// acceleration structure `scene` and the payload `hit` before including it).

// The scene's buffers, read through their device addresses: GL's vertex, index and instance
// buffers are Vulkan buffers, so the ray tracer reads the very bytes GL rasterised.
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Floats { float f[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Uints { uint u[]; };

// ANCHOR: mesh_ids
// chapter 12's `MeshIds`, byte for byte (32 bytes; its unit test checks the offsets). Mesh m's
// instances own the ids [first_id, first_id + instances * triangles), instance by instance.
struct MeshIds {
    uvec2 vertices;      // device address of common::scene::Vertex[] (24 bytes each)
    uvec2 indices;       // device address of uint[3 * triangles]
    uint first_id;       // the id of instance 0's triangle 0, less one
    uint triangles;      // per instance
    uint first_instance; // into the shared instance buffer
    uint instances;
};
layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer Meshes { MeshIds m[]; };
// ANCHOR_END: mesh_ids

// The ray offset, the normal's unpacking, the sample sequence and its rotation: chapter 07's.
#include "sampling.glsl"

// ANCHOR: decode
// Which mesh, instance and triangle an id names: the last mesh whose first id is not above it
// (a binary search over the few meshes), then a division.
void decode(Meshes meshes, uint mesh_count, uint id, out MeshIds mesh, out uint instance, out uint triangle) {
    uint low = 0u, high = mesh_count;
    while (high - low > 1u) {
        uint middle = (low + high) / 2u;
        if (meshes.m[middle].first_id <= id) {
            low = middle;
        } else {
            high = middle;
        }
    }
    mesh = meshes.m[low];
    uint local = id - mesh.first_id;
    instance = mesh.first_instance + local / mesh.triangles;
    triangle = local % mesh.triangles;
}
// ANCHOR_END: decode

// ANCHOR: corner
// A corner of the triangle in the mesh's own coordinates, as (x, y, z, 1).
vec4 object_corner(MeshIds mesh, uint triangle, uint k) {
    uint v = Uints(mesh.indices).u[3u * triangle + k];
    Floats vertices = Floats(mesh.vertices);
    return vec4(vertices.f[6u * v], vertices.f[6u * v + 1u], vertices.f[6u * v + 2u], 1.0);
}

// An instance's object-to-world transform: the top three rows of its matrix.
struct Rows {
    vec4 r0, r1, r2;
};

Rows instance_rows(uvec2 instances, uint instance) {
    Floats rows = Floats(instances);
    uint at = 16u * instance;
    return Rows(vec4(rows.f[at], rows.f[at + 1u], rows.f[at + 2u], rows.f[at + 3u]),
                vec4(rows.f[at + 4u], rows.f[at + 5u], rows.f[at + 6u], rows.f[at + 7u]),
                vec4(rows.f[at + 8u], rows.f[at + 9u], rows.f[at + 10u], rows.f[at + 11u]));
}

// The corner in world space, transformed exactly as gbuffer.vert and visibility.vert transform
// it: the instance's three rows dotted with (position, 1).
vec3 placed(vec4 p, Rows rows) {
    return vec3(dot(rows.r0, p), dot(rows.r1, p), dot(rows.r2, p));
}

// ANCHOR_END: corner

// ANCHOR: barycentrics
// Where the ray from `eye` along `direction` meets the triangle (a, a + e1, a + e2), as
// barycentrics (Moeller-Trumbore). GL covered this pixel's centre with this triangle, so they lie
// inside it but for rounding: clamped, the point stays on the triangle.
vec2 barycentrics(vec3 eye, vec3 direction, vec3 a, vec3 e1, vec3 e2) {
    vec3 p_vec = cross(direction, e2);
    float det = dot(e1, p_vec);
    vec3 to_eye = eye - a;
    float u = det != 0.0 ? dot(to_eye, p_vec) / det : 1.0 / 3.0;
    float v = det != 0.0 ? dot(direction, cross(to_eye, e1)) / det : 1.0 / 3.0;
    u = clamp(u, 0.0, 1.0);
    return vec2(u, clamp(v, 0.0, 1.0 - u));
}
// ANCHOR_END: barycentrics

// The triangle's own unit normal, scaled before normalising (gbuffer.geom); zero for a triangle
// with no plane, which GL covers no pixel with.
vec3 plane_normal(vec3 e1, vec3 e2) {
    vec3 n = cross(e1, e2);
    float largest = max(max(abs(n.x), abs(n.y)), abs(n.z));
    return largest > 0.0 ? normalize(n / largest) : vec3(0.0);
}

// ANCHOR: rebuild
// A pixel's hit, rebuilt from the id GL drew there: the exact point and the triangle's own normal,
// turned to the side the camera sees. Also kept, for chapter 13's reprojection: the corners in
// the mesh's own coordinates and the barycentrics, which place the same point under another
// transform.
struct PixelHit {
    uint instance;
    vec4 o0, o1, o2;
    vec2 uv;
    vec3 position;
    vec3 n; // zero for a triangle with no plane (GL covers no pixel with one)
    float facing; // 1 or -1
};

PixelHit rebuild_hit(Meshes meshes, uint mesh_count, uvec2 instances, uint id, ivec2 pixel, ivec2 size,
                     vec3 eye, mat4 inverse_view_projection) {
    PixelHit h;
    MeshIds mesh;
    uint triangle;
    decode(meshes, mesh_count, id - 1u, mesh, h.instance, triangle);
    h.o0 = object_corner(mesh, triangle, 0u);
    h.o1 = object_corner(mesh, triangle, 1u);
    h.o2 = object_corner(mesh, triangle, 2u);
    Rows now = instance_rows(instances, h.instance);
    vec3 a = placed(h.o0, now);
    vec3 e1 = placed(h.o1, now) - a;
    vec3 e2 = placed(h.o2, now) - a;

    // The ray GL's pixel centre stands for (launch row 0 is GL's bottom row, as in primary.rgen).
    vec2 ndc = (vec2(pixel) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec4 on_far_plane = inverse_view_projection * vec4(ndc, 1.0, 1.0);
    vec3 direction = normalize(on_far_plane.xyz / on_far_plane.w - eye);

    // The point is built from the triangle's corners, not from the eye: its rounding is that of
    // the scene's coordinates, as GL's interpolated position's was, however far away the camera
    // stands.
    h.uv = barycentrics(eye, direction, a, e1, e2);
    h.position = a + h.uv.x * e1 + h.uv.y * e2;

    // The triangle's own normal, facing the camera.
    h.n = plane_normal(e1, e2);
    h.facing = dot(h.n, direction) > 0.0 ? -1.0 : 1.0;
    h.n *= h.facing;
    return h;
}
// ANCHOR_END: rebuild

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
