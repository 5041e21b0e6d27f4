#version 450 core
// Chapter 08: one triangle that covers the screen, made from gl_VertexID alone (no buffer).

void main() {
    vec2 corner = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2); // (0,0), (2,0), (0,2)
    gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}
