#version 450 core
// Chapters 02 and 04: a triangle of (x, y, u, v) vertices straight from a shared buffer.

// The vertex buffer is tightly packed (x, y, u, v) f32 per vertex: 16-byte stride, position at
// offset 0 and uv at offset 8. The chapters bind these locations with glVertexArrayAttribFormat.
layout(location = 0) in vec2 position;
layout(location = 1) in vec2 uv;

layout(location = 0) out vec2 v_uv;

void main() {
    v_uv = uv;
    gl_Position = vec4(position, 0.0, 1.0);
}
