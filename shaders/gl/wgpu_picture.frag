#version 450 core
// Chapter 15: wgpu's picture into GL's framebuffer, and wgpu's depth (a colour image of depths)
// into GL's depth buffer, so that what GL draws next is hidden where wgpu's triangle is nearer.

layout(binding = 0) uniform sampler2D picture;
layout(binding = 1) uniform sampler2D depth;
layout(location = 0) out vec4 colour;

void main() {
    // wgpu's first row is the top of its picture; GL's window counts rows from the bottom.
    ivec2 texel = ivec2(gl_FragCoord.xy);
    texel.y = textureSize(picture, 0).y - 1 - texel.y;
    colour = texelFetch(picture, texel, 0);
    gl_FragDepth = texelFetch(depth, texel, 0).r;
}
