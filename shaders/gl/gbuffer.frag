// ANCHOR: all
#version 450 core
// Chapter 05: the G-buffers, one colour attachment each (the FBO's draw buffers 0, 1, 2).

in vec3 world_position;
in vec3 world_normal;
in float view_depth;
flat in vec3 albedo;
flat in vec3 face_normal; // the triangle's own normal, from gbuffer.geom (chapter 07)

// RGBA32F. w = view depth: > 0 on every covered pixel, 0 where the clear left the background.
layout(location = 0) out vec4 out_position;
// RGBA32F. xyz: the unit shading normal, facing the camera. w: the triangle's geometric normal,
// also facing the camera, packed into one float (see pack_normal).
layout(location = 1) out vec4 out_normal;
// RGBA8.
layout(location = 2) out vec4 out_albedo;

vec2 sign_not_zero(vec2 v) {
    return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

// ANCHOR: pack_normal
// A unit vector in one float: the octahedral map (Cigolle et al., JCGT 2014) folds the sphere onto
// the square [-1, 1]^2; each coordinate is rounded to 12 bits and the pair stored as the integer
// x * 4096 + y, below 2^24, which a float holds exactly. The angle lost to rounding is under 0.1
// degree, far below what moving a ray's origin off the surface or choosing its direction needs.
float pack_normal(vec3 n) {
    vec2 p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    if (n.z < 0.0) {
        p = (1.0 - abs(p.yx)) * sign_not_zero(p);
    }
    uvec2 q = uvec2(round(clamp(p * 0.5 + 0.5, 0.0, 1.0) * 4095.0));
    return float(q.x * 4096u + q.y);
}
// ANCHOR_END: pack_normal

void main() {
    // Both normals face the camera: the ground plane is seen from both sides, and AO (chapter 07)
    // wants the side facing us.
    vec3 face = gl_FrontFacing ? face_normal : -face_normal;
    // The shading normal on the same side as the face: a file's normals may point inwards, or be
    // smoothed across a crease until they point away from the triangle they shade.
    vec3 n = normalize(world_normal);
    if (!(dot(n, face) > 0.0)) {
        n = dot(n, face) < 0.0 ? -n : face; // flipped, or no usable normal (zero, NaN): the face's
    }
    out_normal = vec4(n, pack_normal(face));
    out_position = vec4(world_position, view_depth);
    out_albedo = vec4(albedo, 1.0);
}
// ANCHOR_END: all
