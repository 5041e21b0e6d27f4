#version 450 core
// Chapter 07: each triangle's own (geometric) normal, for the ambient-occlusion rays.
//
// The vertex shader's normals are the mesh's *shading* normals: smooth ones are averaged over the
// faces around each vertex, so inside a triangle they lean away from its plane. Rays sampled around
// them dip below the triangle and hit its neighbours (the "shadow terminator" problem), and a ray
// origin pushed along them can sink into the surface. Occlusion is about the surface itself: this
// pass-through stage sees all three corners at once and computes the plane's normal from them.

// ANCHOR: geometric_normal
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;

in vec3 world_position_[];
in vec3 world_normal_[];
in float view_depth_[];
flat in vec3 albedo_[];
#ifdef TEXTURED
in vec2 uv_[]; // chapter 16
out vec2 uv;
#endif

out vec3 world_position;
out vec3 world_normal;
out float view_depth;
flat out vec3 albedo;
// The triangle's plane, wound as GL winds it: counter-clockwise corners face the viewer when
// gl_FrontFacing is true, in world space as on screen.
flat out vec3 face_normal;

void main() {
    vec3 a = world_position_[0], b = world_position_[1], c = world_position_[2];
    vec3 n = cross(b - a, c - a);
    // A zero-area triangle has no plane, and covers no pixel either: drop it, rather than send a
    // NaN normal (normalize of zero) on to the ray tracer.
    float largest = max(max(abs(n.x), abs(n.y)), abs(n.z));
    if (!(largest > 0.0)) {
        return;
    }
    // Divided by its largest component before normalising: a tiny triangle (a model scaled by
    // 1e-4) has a cross product so small that its squared length would underflow to zero.
    n = normalize(n / largest);
    for (int i = 0; i < 3; i++) {
        gl_Position = gl_in[i].gl_Position;
        world_position = world_position_[i];
        world_normal = world_normal_[i];
        view_depth = view_depth_[i];
        albedo = albedo_[i];
        face_normal = n;
#ifdef TEXTURED
        uv = uv_[i];
#endif
        EmitVertex();
    }
}
// ANCHOR_END: geometric_normal
