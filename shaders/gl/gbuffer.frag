// ANCHOR: all
#version 450 core
// Chapter 05: the G-buffers, one colour attachment each (the FBO's draw buffers 0, 1, 2).

in vec3 world_position;
in vec3 world_normal;
in float view_depth;
flat in vec3 albedo;
flat in vec3 face_normal; // the triangle's own normal, from gbuffer.geom (chapter 07)
#ifdef TEXTURED
// ANCHOR: textured_inputs
// Chapter 16: the material's colour texture, a shared sRGB image: GL decodes each texel to linear
// light before it filters, so levels and neighbours mix as light does.
in vec2 uv;
uniform sampler2D colour;
uniform float cutoff; // alpha below this is a hole; 0 for a material without a cut-out
// ANCHOR_END: textured_inputs
#endif

// RGBA32F. w = view depth: > 0 on every covered pixel, 0 where the clear left the background.
layout(location = 0) out vec4 out_position;
// RGBA32F. xyz: the unit shading normal, facing the camera. w: the triangle's geometric normal,
// also facing the camera, packed into one float (see pack_normal).
layout(location = 1) out vec4 out_normal;
// RGBA8.
layout(location = 2) out vec4 out_albedo;

// pack_normal: the octahedral map, 24 bits (shaders/octahedral.glsl, which Vulkan's shaders
// include too; gbuffer.rs resolves the #include).
#include "octahedral.glsl"

#ifdef TEXTURED
// The sRGB transfer function and its inverse, as GL_SRGB8_ALPHA8 applies them (per channel).
vec3 to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c));
}
vec3 to_srgb(vec3 c) {
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}
#endif

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
    out_normal = vec4(n, float(pack_normal(face)));
    out_position = vec4(world_position, view_depth);
#ifdef TEXTURED
    // ANCHOR: textured
    vec4 texel = texture(colour, uv); // trilinear: two levels, four texels each
    if (texel.a < cutoff) {
        discard; // a hole: no G-buffer, no depth, and the ray tracer sees through it too
    }
    // The G-buffer keeps chapter 08's albedo, a colour as displayed (sRGB-encoded, 8 bits): the
    // texel, filtered in linear light, times the material's colour, encoded once on the way out.
    out_albedo = vec4(to_srgb(to_linear(albedo) * texel.rgb), 1.0);
    // ANCHOR_END: textured
#else
    out_albedo = vec4(albedo, 1.0);
#endif
}
// ANCHOR_END: all
