#version 450 core
// Chapter 04: sample the texture whose memory Vulkan's compute shader wrote.

// binding = 0: texture unit 0, so the chapter needs no glUniform1i to point the sampler at it.
layout(binding = 0) uniform sampler2D image;

layout(location = 0) in vec2 v_uv;
layout(location = 0) out vec4 colour;

void main() {
    colour = texture(image, v_uv);
}
