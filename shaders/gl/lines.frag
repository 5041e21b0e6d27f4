#version 450 core
// Chapter 08: overlay lines, flat coloured. The depth test, not this shader, hides them.

in vec3 v_colour;
layout(location = 0) out vec4 colour;

void main() {
    colour = vec4(v_colour, 1.0);
}
