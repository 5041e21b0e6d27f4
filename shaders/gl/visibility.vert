#version 450 core
// Chapter 12: the visibility buffer's vertex stage. Positions are transformed exactly as
// gbuffer.vert transforms them (the same products in the same order), so that both passes cover
// the same pixels with the same triangles; nothing else is passed on but one id.

// Per vertex (binding 0): common::scene::Vertex's position. Per instance (binding 1, divisor 1):
// the object-to-world rows of common::scene::Instance.
layout(location = 0) in vec3 position;
layout(location = 2) in vec4 row0;
layout(location = 3) in vec4 row1;
layout(location = 4) in vec4 row2;

uniform mat4 view;
uniform mat4 projection;
// This draw's mesh: the id of its instance 0's triangle 0 less one, and its triangles per
// instance.
uniform uint first_id;
uniform uint triangles;

// The id of this instance's triangle 0, less one (gl_InstanceID counts from 0 in every draw;
// visibility.frag adds gl_PrimitiveID + 1, so that 0 stays the background).
flat out uint instance_first_id;

void main() {
    mat4 object_to_world = transpose(mat4(row0, row1, row2, vec4(0.0, 0.0, 0.0, 1.0)));
    vec4 world = object_to_world * vec4(position, 1.0);
    gl_Position = projection * (view * world);
    instance_first_id = first_id + uint(gl_InstanceID) * triangles;
}
