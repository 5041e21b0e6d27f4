#version 450 core
// Chapter 08: overlay lines, in world space, with the scene's camera.

layout(location = 0) in vec3 position;
layout(location = 1) in vec3 line_colour;

uniform mat4 view_projection;

out vec3 v_colour;

void main() {
    v_colour = line_colour;
    gl_Position = view_projection * vec4(position, 1.0);
}
