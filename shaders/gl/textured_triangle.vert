#version 450 core
// Chapter 04: the triangle that shows the image Vulkan computed.

// The vertex buffer is tightly packed (x, y, u, v) f32 per vertex: 16-byte stride, position at
// offset 0 and uv at offset 8. The locations are what glVertexAttribPointer binds.
layout(location = 0) in vec2 position;
layout(location = 1) in vec2 uv;

layout(location = 0) out vec2 v_uv;

void main() {
    v_uv = uv;
    gl_Position = vec4(position, 0.0, 1.0);
}
