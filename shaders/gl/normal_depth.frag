#version 450 core
// Chapter 12's other lean buffer, measured against the ids (`bench --probe layouts`, after
// normal_depth.vert) and not used by the frame: what a trace needs of a hit without the scene's
// buffers, 8 bytes a pixel. x: the triangle's geometric normal, facing the camera, packed as
// gbuffer.frag packs it; y: the view depth's bits. The hit point would come back from the depth
// and the pixel's ray, and albedo would need 4 bytes more.

in vec3 view_position;

layout(location = 0) out uvec2 normal_depth;

// pack_normal: gbuffer.frag's (shaders/octahedral.glsl), as the integer it is.
#include "octahedral.glsl"

void main() {
    // The triangle's own normal from the position's screen-space derivatives; in view space the
    // camera looks down -z, so the side facing it has a positive z.
    vec3 n = normalize(cross(dFdx(view_position), dFdy(view_position)));
    normal_depth = uvec2(pack_normal(n.z < 0.0 ? -n : n), floatBitsToUint(-view_position.z));
}
