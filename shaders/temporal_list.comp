// ANCHOR: all
#version 460
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#extension GL_GOOGLE_include_directive : require
// Chapter 13's first pass (`--passes listed`): all of temporal_ao.rgen's work but the rays, in
// a compute shader. Each pixel rebuilds its hit, takes what the previous frame remembers there
// and stores both its texels with that alone; a pixel that traces this frame is listed for the
// ray launch after, which adds its rays. Why a pass of its own: on the H100 the same work in
// the ray generation shader took 2.22 ms at 3840x2160 when no pixel traced a single ray, 0.50
// ms once the shader had no traceRayEXT in it. A shader that may trace keeps fewer invocations
// in flight, and this work waits on memory: it needs them all.

layout(local_size_x = 16, local_size_y = 16) in;

#include "surface_hit.glsl"
#define FIRST_IMAGE 0
#include "temporal.glsl"

void main() {
    ivec2 size = imageSize(visibility);
    ivec2 pixel = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(pixel, size))) {
        return; // the last groups' overhang
    }
    Cameras c = Cameras(rays.cameras);
    PixelHit h;
    if (!hit_at(c, pixel, size, h)) {
        return;
    }
    uint samples;
    vec2 kept = plan(c, h, pixel, size, samples);
    store(pixel, c, h, blend(kept, 0u, 0u), kept.y);
    if (samples == 0u) {
        return;
    }
    // Listed: at the front if it remembers nothing, else at the back. One atomicAdd per pixel on
    // one of two counts: on the H100 the whole pass took 0.25 ms at 3840x2160 with every pixel
    // listed, and 0.41 ms when each group of 256 added its pixels up in shared memory first.
    List list = List(rays.list);
    if (kept.y == 0.0) {
        list_pixel(atomicAdd(list.counts[FRONT], 1u), pixel, h, kept);
    } else {
        list_pixel(uint(size.x) * uint(size.y) - 1u - atomicAdd(list.counts[BACK], 1u), pixel, h, kept);
    }
}
// ANCHOR_END: all
