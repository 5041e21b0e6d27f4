#version 450 core
// Chapter 02: colours the triangle by its texture coordinates, so that a wrong vertex layout
// (or wrong bytes) shows as wrong colours, not only as a wrong shape.

layout(location = 0) in vec2 v_uv;
layout(location = 0) out vec4 colour;

void main() {
    colour = vec4(v_uv.x, v_uv.y, 1.0 - v_uv.y, 1.0);
}
