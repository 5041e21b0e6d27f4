#version 450 core
// Chapter 05: the G-buffers, one colour attachment each (the FBO's draw buffers 0, 1, 2).

in vec3 world_position;
in vec3 world_normal;
in float view_depth;
flat in vec3 albedo;

// RGBA32F. w = view depth: > 0 on every covered pixel, 0 where the clear left the background.
layout(location = 0) out vec4 out_position;
// RGBA32F, a unit world-space normal facing the camera.
layout(location = 1) out vec4 out_normal;
// RGBA8.
layout(location = 2) out vec4 out_albedo;

void main() {
    vec3 n = normalize(world_normal);
    // The ground plane is seen from both sides: AO (chapter 07) wants the side facing us.
    out_normal = vec4(gl_FrontFacing ? n : -n, 0.0);
    out_position = vec4(world_position, view_depth);
    out_albedo = vec4(albedo, 1.0);
}
