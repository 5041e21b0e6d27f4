#version 460
// Chapter 04: Vulkan computes an animated image that OpenGL then textures onto a triangle.

// 16x16 = 256 invocations per group: a multiple of every vendor's subgroup size, square so that
// neighbouring invocations touch neighbouring pixels.
layout(local_size_x = 16, local_size_y = 16) in;

// rgba8 matches the VK_FORMAT_R8G8B8A8_UNORM image that GL imports as GL_RGBA8; stating it means
// we need no shaderStorageImageWriteWithoutFormat. writeonly: this shader only stores.
layout(set = 0, binding = 0, rgba8) uniform writeonly image2D result;

// Seconds since start; a push constant because it changes every frame and is 4 bytes.
layout(push_constant) uniform Push {
    float time;
} push;

const float TAU = 6.28318530718;

// Inigo Quilez's cosine palette: a smooth, saturated rainbow with no branches.
vec3 palette(float t) {
    return 0.5 + 0.5 * cos(TAU * (t + vec3(0.0, 0.33, 0.67)));
}

void main() {
    ivec2 size = imageSize(result);
    ivec2 pixel = ivec2(gl_GlobalInvocationID.xy);
    // The dispatch is rounded up to whole 16x16 groups, so the last groups overhang the image when
    // its size is not a multiple of 16. An out-of-range imageStore is undefined without the
    // robustness features, so those invocations do nothing.
    if (pixel.x >= size.x || pixel.y >= size.y) {
        return;
    }

    // Pixel centre in [-1, 1], scaled by the aspect ratio so the rings stay round.
    vec2 p = (vec2(pixel) + 0.5) / vec2(size) * 2.0 - 1.0;
    p.x *= float(size.x) / float(size.y);
    float radius = length(p);
    float angle = atan(p.y, p.x);

    // Rings travel outwards at 3 rad/s: frames 1.5 s apart are ~0.7 of a ring out of phase.
    float rings = 0.5 + 0.5 * cos(20.0 * radius - 3.0 * push.time);
    // Hue follows the angle, so a texture that GL shows flipped or rotated looks visibly wrong
    // (rings alone are symmetric and would hide it), and drifts slowly with time.
    float hue = angle / TAU + 0.5 * radius + 0.1 * push.time;
    vec3 colour = palette(hue) * (0.3 + 0.7 * rings);

    imageStore(result, pixel, vec4(colour, 1.0));
}
