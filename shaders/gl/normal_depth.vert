#version 450 core
// `bench --probe layouts`: the vertex stage of normal_depth.frag, the lean buffer chapter 12 was
// measured against. Positions are transformed as visibility.vert transforms them (the same
// products in the same order), so that both cover the same pixels; what goes on is the
// view-space position, from which normal_depth.frag makes the normal and the depth.

// Per vertex (binding 0): common::scene::Vertex's position. Per instance (binding 1, divisor 1):
// the object-to-world rows of common::scene::Instance.
layout(location = 0) in vec3 position;
layout(location = 2) in vec4 row0;
layout(location = 3) in vec4 row1;
layout(location = 4) in vec4 row2;

uniform mat4 view;
uniform mat4 projection;

out vec3 view_position;

void main() {
    mat4 object_to_world = transpose(mat4(row0, row1, row2, vec4(0.0, 0.0, 0.0, 1.0)));
    vec4 world = object_to_world * vec4(position, 1.0);
    vec4 in_view = view * world;
    gl_Position = projection * in_view;
    view_position = in_view.xyz;
}
