#version 450 core
// Chapter 05: one instanced draw per mesh writes the G-buffers.

// Per vertex (buffer binding 0, 24-byte stride): common::scene::Vertex.
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
// Per instance (buffer binding 1, 64-byte stride, divisor 1): common::scene::Instance, which is
// laid out as VkAccelerationStructureInstanceKHR so that chapter 06 builds the TLAS from the same
// buffer. Its 3x4 object-to-world matrix arrives as three rows.
layout(location = 2) in vec4 row0;
layout(location = 3) in vec4 row1;
layout(location = 4) in vec4 row2;
// instanceCustomIndex (low 24 bits) holds the albedo as 0xBBGGRR; the mask is in the high 8.
layout(location = 5) in uint custom_index_and_mask;
#ifdef TEXTURED
// Chapter 16: the vertex's texture coordinate (buffer binding 2, 8-byte stride), in a buffer of
// its own that only textured meshes have.
layout(location = 6) in vec2 uv;
out vec2 uv_;
#endif

uniform mat4 view;
uniform mat4 projection;

// To the geometry stage (gbuffer.geom), which adds each triangle's own normal.
out vec3 world_position_;
out vec3 world_normal_;
out float view_depth_;
flat out vec3 albedo_;

void main() {
    // GLSL matrices are built from columns: the rows become columns, then transpose.
    mat4 object_to_world = transpose(mat4(row0, row1, row2, vec4(0.0, 0.0, 0.0, 1.0)));
    vec4 world = object_to_world * vec4(position, 1.0);
    // Normals take the inverse transpose, which stays right under non-uniform scale.
    world_normal_ = transpose(inverse(mat3(object_to_world))) * normal;
    world_position_ = world.xyz;
    vec4 in_view = view * world;
    view_depth_ = -in_view.z; // the camera looks down -z in view space
    uint c = custom_index_and_mask;
    albedo_ = vec3(c & 0xFFu, (c >> 8) & 0xFFu, (c >> 16) & 0xFFu) / 255.0;
    gl_Position = projection * in_view;
#ifdef TEXTURED
    uv_ = uv;
#endif
}
