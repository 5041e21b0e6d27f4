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

// ANCHOR: group
// How many of this group's pixels each end of the list takes, and where the group's run starts
// there. Half the pixels of a settled view trace in a frame: one atomicAdd each on the same two
// counts would wait on each other, one after the other. The group adds its pixels up in shared
// memory first, and makes one atomicAdd per end.
shared uint group_count[2];
shared uint group_start[2];

void main() {
    if (gl_LocalInvocationIndex < 2u) {
        group_count[gl_LocalInvocationIndex] = 0u;
    }
    barrier();
    // This pixel's place in its group's run, if it traces (no return before the last barrier:
    // every invocation of the group must reach each one).
    ivec2 size = imageSize(visibility);
    ivec2 pixel = ivec2(gl_GlobalInvocationID.xy);
    Cameras c = Cameras(rays.cameras);
    PixelHit h;
    vec2 kept = vec2(0.0);
    uint samples = 0u, end = FRONT, place = 0u;
    // The last groups' overhang is outside the picture.
    if (all(lessThan(pixel, size)) && hit_at(c, pixel, size, h)) {
        kept = plan(c, h, pixel, size, samples);
        store(pixel, c, h, blend(kept, 0u, 0u), kept.y);
        end = kept.y == 0.0 ? FRONT : BACK; // nothing remembered: at the front
        place = samples > 0u ? atomicAdd(group_count[end], 1u) : 0u;
    }
    barrier();
    if (gl_LocalInvocationIndex < 2u) {
        uint e = gl_LocalInvocationIndex;
        group_start[e] = atomicAdd(List(rays.list).counts[e], group_count[e]);
    }
    barrier();
    if (samples > 0u) {
        uint at = group_start[end] + place;
        list_pixel(end == FRONT ? at : uint(size.x) * uint(size.y) - 1u - at, pixel, h, kept);
    }
}
// ANCHOR_END: group
// ANCHOR_END: all
